"""Learning the contact stiffness K(q) and damping D(q) from MuJoCo rollouts.

Installed as ``torchcontact.learn``; one module per stage:

- :mod:`~torchcontact.learn.scenes`: a MuJoCo plant with the paper's MPC model of it;
- :mod:`~torchcontact.learn.policies`: random reach-and-push and MPC action sources;
- :mod:`~torchcontact.learn.data`: collect, store (the file format) and load transitions;
- :mod:`~torchcontact.learn.fit`: precomputed steps, the training loop, checkpoints;
- :mod:`~torchcontact.learn.networks`: a K network of contact features in the object frame;
- :mod:`~torchcontact.learn.evaluate`: one-step and rollout errors, the constant-K sweep;
- :mod:`~torchcontact.learn.job`: ``torchcontact learn-k``.
"""
