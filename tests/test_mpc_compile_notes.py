"""The first compiled step's messages: a notice, and only the known-harmless warnings dropped."""

import logging
import warnings

from torchcontact.mpc.compile_notes import compile_notice, quiet_known_inductor_warnings


def test_only_the_known_harmless_inductor_messages_are_dropped(caplog):
    quiet_known_inductor_warnings()
    logger = logging.getLogger("torch._inductor.ir")
    with caplog.at_level(logging.WARNING, logger="torch._inductor.ir"):
        logger.warning(
            "aten.linalg_solve_triangular.default is missing a c-shim implementation, "
            "using proxy executor as fallback"
        )
        logger.warning("some other inductor warning")
    assert [r.getMessage() for r in caplog.records] == ["some other inductor warning"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        quiet_known_inductor_warnings.__wrapped__()  # the filters, inside this context
        warnings.warn(
            "`torch._prims_common.check` is deprecated and will go", FutureWarning, stacklevel=2
        )
        warnings.warn("another deprecation", FutureWarning, stacklevel=2)
    assert [str(w.message) for w in caught] == ["another deprecation"]


def test_the_notice_names_the_scene_and_the_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path))
    notice = compile_notice("trifinger with cube", 1234)
    assert "trifinger with cube" in notice and str(tmp_path) in notice and "pid 1234" in notice
