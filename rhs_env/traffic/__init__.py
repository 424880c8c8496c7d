"""A compiled traffic core for the straight-road scenes, checked against highway-env (its oracle).

``gym.make("rhs-highway-v0", sim="compiled")`` (any ``rhs-highway-*`` id, ``rhs-dense-v0``, ``rhs-paper-v0``)
steps the traffic with :mod:`rhs_env.traffic.core` (numba kernels over arrays) instead of highway-env's
Python; ``sim="highway-env"`` (the default) keeps highway-env's own code. highway-env still builds the scene
at reset (:mod:`rhs_env.traffic.state` packs it), and the vehicle objects are written back after every step
(:mod:`rhs_env.traffic.sync`). ``scripts/traffic_alignment.py`` drives both with the same actions.

Modules: :mod:`~rhs_env.traffic.core` (kernels), :mod:`~rhs_env.traffic.state` (packing, what is supported),
:mod:`~rhs_env.traffic.sync` (write-back), :mod:`~rhs_env.traffic.engine` (the env's driver).
"""
