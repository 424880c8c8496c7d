"""scripts/benchmark.py: the sections' bookkeeping (not the speeds: those are never asserted)."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from rhs_studies import benchmark


def test_floor_times_the_noise_and_fft_of_every_sample_of_a_scan():
    f = benchmark.bench_floor(grid_deg=5.0, seed=0, repeats=2)
    assert f["samples_per_scan"] == 4 * 18 * 4 * 400  # 4 radars x I slots (90 deg / 5 deg) x C chirps x N samples
    assert f["synthesis_noise_ms"] > 0 and f["range_fft_ms"] > 0
    assert f["floor_ms"] == pytest.approx(f["synthesis_noise_ms"] + f["range_fft_ms"])
    assert f["range_noise_ms"] > 0


def _result(base_ms: float, slam_stage_ms: dict) -> dict:
    envs = {"rhs-highway-v0": {"ms_per_step": base_ms},
            "rhs-highway-slam-v0": {"ms_per_step": 3 * base_ms, "slam_stage_ms": slam_stage_ms}}
    floor = {"samples_per_scan": 576000, "synthesis_noise_ms": 5.0, "range_fft_ms": 3.0, "floor_ms": 8.0}
    return {"envs": envs, "floor": floor}


def test_radar_budget_follows_from_the_goals():
    b = benchmark.radar_budget(_result(20.0, {"update": 2.0, "registration": 1.0}))
    # radar env >= 0.75 x base steps/s <=> base + radar <= base / 0.75
    assert b["radar_budget_ms"] == pytest.approx(20.0 / benchmark.GOALS["radar_env_over_base"] - 20.0)
    assert b["radar_budget_with_slam_ms"] == pytest.approx(20.0 / benchmark.GOALS["slam_env_over_base"] - 20.0 - 3.0)
    assert b["floor_ms"] == 8.0
    assert benchmark.radar_budget({"envs": {}}) is None


def test_markdown_sets_the_floor_beside_the_budget():
    res = _result(20.0, {"update": 2.0})
    res.update(machine={"cpus": 2, "load_average": [0.1, 0.1, 0.1]}, settings={"grid_deg": 1.0})
    res["envs"]["rhs-highway-radar-v0"] = {"ms_per_step": 40.0}
    for r in res["envs"].values():
        r.update(steps_per_s=1e3 / r["ms_per_step"], radar_stage_ms=None, slam_stage_ms=r.get("slam_stage_ms"))
    res["envs"].update(radar_added_ms=20.0, radar_slam_added_ms=40.0, radar_added_over_base=1.0,
                       radar_slam_added_over_base=2.0)
    text = benchmark.markdown(res)
    assert "noise 5.0 ms + range FFT 3.0 ms = 8.0 ms, before detection and OMP. The goals" in text
    res["floor"]["range_noise_ms"] = 2.5
    assert "at half rate) 2.5 ms. The goals leave" in benchmark.markdown(res)
    assert f"leave the radar {20.0 / 0.75 - 20.0:.1f} ms" in text


def test_budget_counts_the_observation_the_radar_envs_skip():
    res = _result(20.0, {"update": 2.0, "registration": 1.0})
    res["envs"]["kinematics_observation_ms"] = 3.5
    b = benchmark.radar_budget(res)
    assert b["radar_budget_ms"] == pytest.approx(20.0 / benchmark.GOALS["radar_env_over_base"] - 20.0 + 3.5)
    assert b["radar_budget_with_slam_ms"] == pytest.approx(20.0 / benchmark.GOALS["slam_env_over_base"] - 20.0 + 3.5 - 3.0)


def test_stage_table_and_start_line():
    envs = {"rhs-highway-slam-v0": {"radar_stage_ms": {"omp": 10.0}, "slam_stage_ms": {"associate": 0.5}},
            "rhs-highway-slam-v0 (numpy kernels)": {"radar_stage_ms": {"omp": 20.0}, "slam_stage_ms": {"associate": 2.0}}}
    table = benchmark.stages_before_after(envs)
    assert table == {"radar.omp": {"numpy": 20.0, "compiled": 10.0}, "slam.associate": {"numpy": 2.0, "compiled": 0.5}}
    start = {"cold_s": 12.0, "warm_s": 4.0, "cold_process_s": 13.0, "warm_process_s": 4.5, "load_average_start": [1.0, 1, 1]}
    text = "\n".join(benchmark._md_start({"start": start}))
    assert "12.0 s with an empty kernel cache" in text and "4.0 s with the cache" in text
    goals = benchmark._goals({"start": start})
    assert goals["start_cold_s"]["met"] and goals["start_warm_s"]["met"]
    assert not benchmark._goals({"start": {**start, "warm_s": 6.0}})["start_warm_s"]["met"]
    several = {**start, "repeats": 3, "cold_runs_s": [11.0, 12.0, 31.0]}  # the median decides, every run is shown
    assert "median of 3 (cold: 11.0, 12.0, 31.0 s)" in "\n".join(benchmark._md_start({"start": several}))
    assert "background compile ended 40.0 s after" in "\n".join(benchmark._md_start({"start": {**start, "background_runs_s": [40.0]}}))
    before = os.environ.get("RHS_SLAM_BACKGROUND_COMPILE")
    with pytest.raises(SystemExit):
        benchmark.main(["--sections", "start", "--start-repeats", "0"])
    assert os.environ.get("RHS_SLAM_BACKGROUND_COMPILE") == before, "main() left the background compile switched off"


def test_ratio_interval_brackets_the_ratio_and_narrows_with_blocks():
    """The bootstrap interval of base / env time over round-robin blocks holds the ratio; more blocks, narrower."""
    from rhs_studies.benchmark import ratio_interval

    rng = np.random.default_rng(0)
    widths = []
    for n in (20, 200):
        base = rng.normal(1.0, 0.1, n)
        env = base / 0.7 * rng.normal(1.0, 0.05, n)  # the env 0.7x the base's steps/s, its own noise on top
        lo, hi = ratio_interval(base, env)
        assert lo <= base.sum() / env.sum() <= hi and lo < 0.7 < hi + 0.02
        widths.append(hi - lo)
    assert widths[1] < 0.5 * widths[0]
    assert ratio_interval(np.ones(10), np.full(10, 2.0)) == [0.5, 0.5]


def test_pooled_runs_sum_the_blocks_and_widen_the_interval_with_the_spread_between_runs():
    rng = np.random.default_rng(1)

    def run(base_ms: float, env_ms: float) -> dict:
        blocks = {"rhs-highway-v0": base_ms, "rhs-highway-radar-v0": env_ms, "rhs-highway-slam-v0": 1.1 * env_ms}
        out: dict = {"blocks_s": {}, "load_average_start": [0.5, 0.5, 0.5]}
        for env_id, ms in blocks.items():
            b = 5 * ms / 1e3 * (1 + 0.01 * rng.standard_normal(60))
            out["blocks_s"][env_id] = b.tolist()
            out[env_id] = {"steps": 300, "steps_per_s": 300 / b.sum(), "ms_per_step": 1e3 * b.sum() / 300,
                           "radar_stage_ms": {"omp": env_ms - base_ms}, "slam_stage_ms": None}
        benchmark._ratios(out)
        return out

    same = benchmark.pool_env_runs([run(25.0, 35.0) for _ in range(3)])
    apart = benchmark.pool_env_runs([run(25.0, 35.0), run(29.0, 37.0), run(27.0, 36.0)])
    assert same["radar_env_over_base"] == pytest.approx(25 / 35, rel=0.01)
    # the pooled ratio is total base time over total env time, between the runs' own ratios
    assert min(r["radar_env_over_base"] for r in apart["runs"]) < apart["radar_env_over_base"] < max(
        r["radar_env_over_base"] for r in apart["runs"])
    assert apart["rhs-highway-v0"]["ms_per_step"] == pytest.approx(27.0, rel=0.01)
    assert apart["rhs-highway-radar-v0"]["radar_stage_ms"]["omp"] == pytest.approx(np.mean([10.0, 8.0, 9.0]))
    width = {k: d["radar_env_over_base_ci"][1] - d["radar_env_over_base_ci"][0] for k, d in (("same", same), ("apart", apart))}
    assert width["apart"] > 3 * width["same"]
    assert len(apart["runs"]) == 3 and len(apart["blocks_s"]["rhs-highway-v0"]) == 180


def test_env_runs_in_fresh_processes_pool_into_one_record():
    """Two tiny runs of the envs section (subprocesses) pool into the record the README's speed table reads."""
    out = benchmark.bench_envs_runs(steps=4, seed=0, grid_deg=5.0, block=2, runs=2)
    assert [out[env_id]["steps"] for env_id in benchmark.POOLED_ENVS] == [8, 8, 8]
    assert len(out["runs"]) == 2 and "rhs-highway-slam-v0 (numpy kernels)" in out
    assert 0 < out["radar_env_over_base_ci"][0] <= out["radar_env_over_base_ci"][1]
    assert set(out["stages_before_after"]) and "Pooled over 2 runs" in "\n".join(
        benchmark._md_envs({"envs": out, "settings": {"grid_deg": 5.0}}))


def test_machine_scaling_times_one_and_two_spin_processes():
    m = benchmark.machine_scaling(repeats=1)
    assert len(m["two_over_one_runs"]) == 1 and 0.2 < m["two_over_one_median"] < 4.0  # two cores: about 1-2


def test_training_rounds_pool_each_rate_and_keep_each_rounds_ratio(monkeypatch):
    import agents.algos.train

    # per round: (slam, base) with update_threads="auto", then (slam, base, fast slam) with the default threads, then
    # the fast slam env through the native vector env in worker processes
    rates = iter([30.0, 50.0, 40.0, 60.0, 200.0, 180.0, 20.0, 50.0, 40.0, 60.0, 240.0, 220.0])

    def fake_train(algo, env_id, timesteps, out, **kwargs):
        if env_id == "rhs-highway-slam-fast-v0":  # the exact SLAM env's hyperparameters, under the fast id
            from agents.algos.hyperparams import load_hyperparams

            assert load_hyperparams(algo, env_id, kwargs["hyperparams"]) == load_hyperparams(algo, "rhs-highway-slam-v0")
        else:
            assert kwargs["hyperparams"] is None
        assert (kwargs.get("native_workers"), kwargs["n_envs"]) in ((None, 2), (2, 8))
        rate = next(rates)
        timing = {"update_threads": 2 if kwargs["update_threads"] else None, "setup_s": 1.0, "learn_s": timesteps / rate,
                  "steady_steps_per_s": rate, "steady_collect_s_per_rollout": 5.0, "steady_update_s_per_rollout": 0.1}
        return {"timesteps": timesteps, "steps_per_s": rate, "timing": timing}

    monkeypatch.setattr(agents.algos.train, "train", fake_train)
    t = benchmark.bench_training(512, seed=0, repeats=2)
    slam = t["default"]["rhs-highway-slam-v0"]
    assert slam["steady_runs"] == [40.0, 40.0] and slam["steady_steps_per_s"] == pytest.approx(40.0)
    auto_slam = t["update_threads_auto"]["rhs-highway-slam-v0"]
    assert auto_slam["steady_steps_per_s"] == pytest.approx(2 / (1 / 30 + 1 / 20))  # steps over time: harmonic mean
    assert t["update_threads_auto"]["ratio_runs"] == [0.6, 0.4]
    assert t["ppo_slam_over_base"] == pytest.approx(40.0 / 60.0) and t["repeats"] == 2
    assert t["rhs-highway-v0"] is t["default"]["rhs-highway-v0"]
    fast = t["default"]["rhs-highway-slam-fast-v0"]
    assert fast["steady_steps_per_s"] == pytest.approx(2 / (1 / 200 + 1 / 240))
    assert "rhs-highway-slam-fast-v0" not in t["update_threads_auto"]
    assert t["ppo_fast_over_exact"] == pytest.approx(fast["steady_steps_per_s"] / 40.0)
    assert t["ppo_fast_over_exact_runs"] == [5.0, 6.0]
    text = "\n".join(benchmark._md_ratios({"training": t}))
    assert "0.667 x" in text and "Pooled over 2 rounds" in text and "0.60, 0.40" in text
    assert "2 subprocess envs each: 5.45 x (each round: 5.00, 6.00)" in text
    native = t["native"]["rhs-highway-slam-fast-v0"]
    assert native["steady_steps_per_s"] == pytest.approx(2 / (1 / 180 + 1 / 220)) and native["workers"] == 2
    assert t["ppo_fast_native_over_exact"] == pytest.approx(native["steady_steps_per_s"] / 40.0)
    assert t["ppo_fast_native_over_exact_runs"] == [4.5, 5.5]
    assert "8 envs in the native vector env on 2 worker processes" in text and "(goal >= 5; each round: 4.50, 5.50)" in text
    goals = benchmark._goals({"training": t})
    assert not goals["ppo_fast_native_over_exact"]["met"] and "ppo_fast_over_exact" not in goals



def test_kernel_clock_times_the_wrapped_kernels_and_restores_them():
    import types

    mod = types.SimpleNamespace(k=lambda x: (time.sleep(0.01), 2 * x)[1])
    original = mod.k
    clock = benchmark._KernelClock({"slam": [(mod, "k")]})
    with clock:
        assert mod.k(3) == 6 and mod.k is not original
    assert mod.k is original and clock.seconds["slam"] >= 0.009  # one call of 10 ms
    targets = benchmark._kernel_targets()
    assert {name for _, name in targets["slam"]} >= {"mahalanobis_association", "proposal_terms", "icp_search"}
    assert [name for _, name in targets["traffic"]] == ["simulate"]


def test_targets_table_ratios_and_goals():
    def env(rate, radar=0.0, slam=0.0, floors=None):
        return {"steps": 10, "steps_per_s": rate, "step_ms": 1e3 / rate, "radar_ms": radar, "slam_ms": slam,
                "traffic_and_rest_ms": 1e3 / rate - radar - slam, "floors": floors or {}}

    t = {"load_average_start": [1.0, 1.0, 1.0], "highway-fast-v0": env(20.0),
         "rhs-highway-slam-v0": env(32.0, 12.0, 8.0, {"traffic_kernels_ms": 0.8, "slam_kernels_ms": 2.5}),
         "rhs-highway-slam-fast-v0": env(130.0, 2.0, 3.0, {"traffic_kernels_ms": 0.8, "slam_kernels_ms": 2.0}),
         "slam_over_highway_fast": 1.6, "slam_over_highway_fast_ci": [1.5, 1.7],
         "slam_fast_over_highway_fast": 6.5, "slam_fast_over_highway_fast_ci": [6.1, 6.9]}
    text = "\n".join(benchmark._md_targets({"targets": t, "floor": {"floor_ms": 4.5}}))
    assert "| rhs-highway-slam-fast-v0 | 130.0 | 7.69 | 2.00 | 3.00 | 2.69 | 0.80 / 2.00 |" in text
    assert "`rhs-highway-slam-v0` 1.60 x `highway-fast-v0` (95 % [1.50, 1.70], goal >= 1.5 x)" in text
    assert "sample floor (noise + range FFT of every IQ sample): 4.5 ms" in text
    goals = benchmark._goals({"targets": t})
    assert goals["slam_fast_over_highway_fast"]["met"] and goals["slam_fast_over_highway_fast"]["ci"] == [6.1, 6.9]
    assert not benchmark._goals({"targets": {**t, "slam_over_highway_fast": 1.4}})["slam_over_highway_fast"]["met"]
