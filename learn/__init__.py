"""Learning the contact stiffness K(q) and damping D(q) from data (installed as torchcontact.learn)."""
