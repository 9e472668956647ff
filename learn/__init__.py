"""Learning the contact stiffness K(q) and damping D(q) from data.

Installed as ``torchcontact.learn``.
"""
