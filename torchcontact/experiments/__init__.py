"""Reproductions of the paper's contact-simulation experiments (box pushing, full dynamics)."""
