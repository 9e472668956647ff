"""Environment descriptions: a robot, its object's plant, the model's system, cost, tasks and
presets, one registered instance per environment (``fingertips``, ``trifinger``, ``allegro``)."""
