"""The training algorithms and their plumbing (``rhs-slam train``).

* the algorithms: :mod:`agents.algos.train` (PPO / DQN with stable-baselines3, and the entry of every
  ``--algo``), :mod:`agents.algos.imitation` (DAgger), :mod:`agents.algos.finetune` (PPO on top of a DAgger
  student, asymmetric actor-critic) and :mod:`agents.algos.rllib` (the Ray RLlib backend);
* a run's set-up: :mod:`agents.algos.hyperparams` (the YAML entries and the run's settings; their
  ``policy_kwargs`` parsed safely by :mod:`agents.algos.policy_kwargs`), :mod:`agents.algos.vec_env` (the vector
  envs and their workers), :mod:`agents.algos.run_checks` (the argument checks), :mod:`agents.algos.threads`
  (torch's threads) and :mod:`agents.algos.run_records` (what a run writes);
* during a run: :mod:`agents.algos.callbacks` (stable-baselines3 callbacks), :mod:`agents.algos.resume`
  (stop on a signal, resume from the last good checkpoint) and :mod:`agents.algos.shaping` (the training reward's
  shaping terms).
"""
