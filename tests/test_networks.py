"""ObjectContactNetwork: features in the object's frame, one value per facet, by name."""

import math

import pytest
import torch
from test_contacts import random_contacts

from torchcontact import PARAMETERIZATIONS, Contacts, Parameterization, parameterization
from torchcontact.networks import ObjectContactNetwork
from torchcontact.rotations import quaternion_to_matrix
from torchcontact.stiffness import Constant, register_parameterization


def _state(batch, robot=3, seed=0):
    generator = torch.Generator().manual_seed(seed)
    q = torch.randn(*batch, 7 + robot, generator=generator)
    q[..., 3:7] /= torch.linalg.vector_norm(q[..., 3:7], dim=-1, keepdim=True)
    return q


def test_outputs_one_positive_value_per_row_starting_near_value():
    net = ObjectContactNetwork(facets=4, hidden=8, value=2.0)
    contacts = random_contacts(5, 10, batch=(3,), dtype=torch.float32)
    out = net(contacts, 4, q=_state((3,)))
    assert out.shape == (3, 20)
    assert (out > 0).all()
    torch.testing.assert_close(out, torch.full_like(out, 2.0), atol=0.1, rtol=0)


def test_features_are_the_contact_seen_from_the_object():
    net = ObjectContactNetwork(facets=4, hidden=8, distance_scale=0.01, object_size=0.1)
    contacts = random_contacts(2, 10, dtype=torch.float32)
    q = _state(())
    features = net.contact_features(contacts, q)
    assert features.shape == (2, 13)
    rotation = quaternion_to_matrix(q[3:7])
    normal = contacts.frame[:, 0, :]
    torch.testing.assert_close(features[:, 0], (contacts.phi / 0.01).clamp(-10, 10))
    torch.testing.assert_close(features[:, 1:4], normal)
    torch.testing.assert_close(features[:, 4:7], normal @ rotation)
    torch.testing.assert_close(features[:, 7:10], (contacts.position - q[:3]) / 0.1 @ rotation)
    torch.testing.assert_close(features[:, 10:13], rotation[2].expand(2, 3))


def test_missing_inputs_and_bad_settings_raise():
    net = ObjectContactNetwork(facets=4, hidden=8)
    contacts = random_contacts(2, 10, dtype=torch.float32)
    with pytest.raises(ValueError, match="q is required"):
        net(contacts, 4)
    with pytest.raises(ValueError, match="facets must be 4"):
        net(contacts, 3, q=_state(()))
    fields = ("phi", "jac_normal", "jac_tangent", "mu", "active")
    bare = Contacts(**{name: getattr(contacts, name) for name in fields})
    with pytest.raises(ValueError, match="contacts must carry frame and position"):
        net(bare, 4, q=_state(()))
    for name in ("value", "distance_scale", "object_size"):
        with pytest.raises(ValueError, match=name):
            ObjectContactNetwork(4, **{name: 0.0})


def test_built_by_name_from_the_registry():
    assert PARAMETERIZATIONS["object_contact_network"] is ObjectContactNetwork
    net = parameterization("object_contact_network", facets=6, hidden=4)
    assert isinstance(net, ObjectContactNetwork) and net.facets == 6


def test_register_parameterization_adds_a_name_and_refuses_bad_ones():
    class Twice(Constant):
        """A constant, registered under a second name."""

    try:
        assert register_parameterization("twice_for_test", Twice) is Twice
        built = parameterization("twice_for_test", value=3.0)
        assert isinstance(built, Twice) and math.isclose(built(None, 4).item(), 3.0)
    finally:
        PARAMETERIZATIONS.pop("twice_for_test", None)
    with pytest.raises(ValueError, match="new parameterization name, got 'constant'"):
        register_parameterization("constant", Twice)
    with pytest.raises(ValueError, match="name must be a non-empty string"):
        register_parameterization("", Twice)
    for bad in (torch.nn.Linear, Constant(), "Constant"):
        with pytest.raises(ValueError, match="'.*' is not a valid parameterization"):
            register_parameterization("bad_for_test", bad)
    assert "bad_for_test" not in PARAMETERIZATIONS
    assert issubclass(ObjectContactNetwork, Parameterization)
