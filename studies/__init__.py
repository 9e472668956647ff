"""Studies: the code that reproduces the README's figures, beside the library, not installed.

Each module runs one experiment of the paper or one sweep of ours and reports it through
:mod:`studies.report`: ``box_pushing`` (CF vs the QP, time per step), ``full_dynamic``
(settings 1-3 against MuJoCo), ``model_tradeoff`` and ``mpc_tradeoff`` (the speed-accuracy
sweeps), ``ipopt_baseline`` with ``casadi_kinematics`` (the paper's CasADi/IPOPT MPC, the
speed baseline). The scripts in ``benchmarks/`` run them from the repository root.
"""

import torchcontact.sim  # noqa: E402, F401  (chooses the GL backend before a study imports mujoco)
