"""Contact-implicit MPC through the complementarity-free model (installed as torchcontact.mpc)."""

from torchcontact.mpc import hybrid as _hybrid  # noqa: E402, F401  registers the "hybrid" planner
