"""Property-based fuzzing of the env API on a cheap env (hypothesis; profile in ``tests/fuzz_settings.py``).

Random orders of ``reset`` (seeds and options of any type), ``step`` (actions of any type), ``render``
and ``close`` on ``rhs-highway-v0`` (two lanes, two cars, 2-step episodes), with the discrete
meta-actions or the continuous ones. The rule: each call succeeds (a step's observation and reward
finite) or raises a clean error: ``ValueError`` / ``TypeError`` naming the argument (``seed``,
``options``, ``action``), gymnasium's ``ResetNeeded`` before the first reset, and
:class:`rhs_env.envs.EnvClosedError` for ``step`` / ``render`` after ``close``; never another exception.
"""

from __future__ import annotations

import math
import warnings

import fuzz_settings  # noqa: F401  (loads the hypothesis profile)
import gymnasium as gym
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import rhs_env  # noqa: F401  (registers the ids)
from rhs_env.envs import EnvClosedError

SMALL = {"vehicles_count": 2, "lanes_count": 2, "duration": 0.4}
VALUES = st.one_of(
    st.integers(-3, 8), st.integers(-(2**70), 2**70), st.floats(), st.none(), st.booleans(), st.text(max_size=3),
    st.lists(st.floats(-2, 2), max_size=3), st.just({}), st.just({"config": {"lanes_count": 2}}),
    st.just({"bogus": 1}), st.sampled_from([np.int64(2), np.array([3]), np.array([[1]]), np.array([0.1, -0.2]),
                                            np.array(["1", "0"]), np.array([0.5, math.nan]), np.float32(0.3)]),
)
OPS = st.lists(st.one_of(st.tuples(st.just("reset"), VALUES), st.tuples(st.just("reset_options"), VALUES),
                         st.tuples(st.just("step"), VALUES), st.tuples(st.just("render"), st.none()),
                         st.tuples(st.just("close"), st.none())), min_size=1, max_size=7)
NAMES = {"reset": "seed", "reset_options": "options", "step": "action"}


def _finite(obs) -> bool:
    return all(np.all(np.isfinite(np.asarray(v, dtype=float))) for v in
               (obs.values() if isinstance(obs, dict) else [obs]))


@settings(max_examples=40)
@given(ops=OPS, continuous=st.booleans(), render=st.booleans())
def test_any_order_of_calls_succeeds_or_fails_cleanly(ops, continuous, render):
    kw = {**SMALL, **({"action": {"type": "ContinuousAction"}} if continuous else {}),
          **({"render_mode": "rgb_array"} if render else {})}
    env = gym.make("rhs-highway-v0", **kw)
    closed = False
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # steps after the end of an episode warn (checked elsewhere)
            for op, value in ops:
                try:
                    if op == "reset":
                        env.reset(seed=value)
                        closed = False
                    elif op == "reset_options":
                        env.reset(seed=0, options=value)
                        closed = False
                    elif op == "step":
                        obs, reward, *_ = env.step(value)
                        assert _finite(obs) and math.isfinite(float(reward)), (value, obs, reward)
                    elif op == "render":
                        frame = env.render()
                        assert frame is None or np.asarray(frame).ndim == 3
                    else:
                        env.close()
                        closed = True
                except EnvClosedError as exc:
                    assert closed and op in ("step", "render"), (op, exc)
                except gym.error.ResetNeeded:
                    assert op in ("step", "render")
                except (ValueError, TypeError) as exc:
                    assert NAMES.get(op, "?") in str(exc), (op, value, exc)
    finally:
        env.close()
