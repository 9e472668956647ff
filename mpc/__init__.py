"""Contact-implicit MPC through the complementarity-free model (installed as torchcontact.mpc)."""
