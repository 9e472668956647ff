"""Learning the contact stiffness K(q) and damping D(q) from MuJoCo rollouts.

Installed as ``torchcontact.learn``; one module per stage:

- :mod:`~torchcontact.learn.scenes`: an environment's plant with the paper's model of it;
- :mod:`~torchcontact.learn.policies`: random reach-and-push and MPC action sources;
- :mod:`~torchcontact.learn.data`: collect, store (the file format) and load transitions;
- :mod:`~torchcontact.learn.fit`: precomputed steps, the training loop; :func:`~torchcontact
  .learn.fit.fit` on plain tensors gives what :func:`~torchcontact.checkpoint.save_model`
  writes (a checkpoint and its manifest) and :func:`~torchcontact.checkpoint.load_model` reads;
- :mod:`~torchcontact.learn.evaluate`: one-step and rollout errors, the constant-K sweep;
``torchcontact learn-k`` (:mod:`torchcontact.cli.learn_k`) runs them end to end; the learned
K network of contact features in the object frame is :mod:`torchcontact.networks`.
"""
