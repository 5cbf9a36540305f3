"""Worker processes for a diagnosis round (:mod:`sionna_mmir.residual.workers`):
the settings, the pool's task order, and a diagnosis that is the same on
one process and on two."""
from __future__ import annotations

import os
import pickle

import numpy as np
import pytest

from sionna_mmir.effects import EffectContext, EffectModel
from sionna_mmir.effects.model import Component
from sionna_mmir.effects.library.channel_gain import ChannelGain
from sionna_mmir.effects.library.noise_floor import NoiseFloor
from sionna_mmir.effects.library.scatterer import MissingScatterer
from sionna_mmir.errors import ConfigError
from sionna_mmir.radar.config import RadarConfig
from sionna_mmir.residual import diagnose
from sionna_mmir.residual import adoption
from sionna_mmir.residual.adoption import _effect_position, _in_order, _keep
from sionna_mmir.residual.workers import FitPool, available_cores, check_workers

from helpers import point_targets_adc


def test_01_workers_setting():
    assert check_workers("auto") == available_cores() >= 1
    assert check_workers(None) == available_cores()
    assert check_workers("3") == 3 and check_workers(1) == 1
    for bad in (0, -1, "0", "1.5", 2.5, "many", "", True):
        with pytest.raises(ConfigError, match="--workers"):
            check_workers(bad)


def test_02_pool_returns_results_in_task_order_and_reports_each_task_once():
    tasks = [(k,) for k in range(7)]
    seen = []
    out = FitPool(2).map(pow, 3, tasks, done=seen.append)      # pow(shared, k) in a worker
    assert out == [3 ** k for k in range(7)]
    assert sorted(seen) == list(range(7))
    assert FitPool(1).map(pow, 3, tasks) == out
    # a pool pickles as its size only (a checkpointed run holds one)
    assert pickle.loads(pickle.dumps(FitPool(2))).workers == 2


def test_02b_follow_up_tasks_run_after_the_result_that_calls_for_them():
    """``follow(i, result)`` appends tasks that start once a worker is free;
    the results list holds the given tasks, then each follow-up in the order
    it was asked for, and is the same on processes and here (a chain: every
    multiple of 3 below 10 asks for the next one)."""
    import operator

    def follow(i, r):
        return [(r + 3,)] if r % 3 == 0 and r < 10 else []

    for workers in (1, 2):
        seen = []
        out = FitPool(workers).map(operator.add, 0, [(0,), (1,)], done=seen.append,
                                   follow=follow)
        assert out == [0, 1, 3, 6, 9, 12]
        assert sorted(seen) == list(range(6))


def test_02c_follow_ups_start_before_the_tasks_not_yet_started():
    """At most one task per worker is in flight; a follow-up goes to the
    front of the queue (in the executor's own queue it would wait behind
    every given task, at the end of a ranking round).  An in-process
    executor records the order in which tasks are started."""
    import operator
    from concurrent.futures import Future

    class _Recording:
        def __init__(self):
            self.started = []

        def submit(self, call, fn, path, task):
            self.started.append(task[0])
            fut = Future()
            fut.set_result(fn(0, *task))
            return fut

    ex = _Recording()
    out = FitPool(2)._run_queue(ex, operator.add, None, [(0,), (1,), (2,), (3,)], None,
                                lambda i, r: [(10,), (11,)] if r == 0 else [])
    assert out == [0, 1, 2, 3, 10, 11]
    assert ex.started == [0, 1, 10, 11, 2, 3]


class _Eff:
    """A toy effect: only its identity matters."""

    kind = "mean"

    def __init__(self, name):
        self.name = name


class _Toy:
    """A stand-in model whose components hold one number each; the NLL of a
    trial falls with every even number in the model."""

    def __init__(self, values):
        self.components = [Component(effect=_Eff(f"e{k}"), specs={}, values={"v": np.array(v)})
                           for k, v in enumerate(values)]
        self.nuisance = Component(effect=None, specs={}, values={})

    def copy(self):
        new = _Toy([])
        new.components = [c.copy() for c in self.components]
        new.nuisance = self.nuisance.copy()
        return new

    def remove(self, comp):
        self.components.remove(comp)

    restore = EffectModel.restore

    def numbers(self):
        return [int(c.values["v"]) for c in self.components]

    def nll(self):
        return 10.0 - sum(1 for v in self.numbers() if v % 2 == 0)


def _toy_restart(model, i, maxiter):
    """An odd number restarts to the next even one (a better NLL), an even one
    to an odd one (worse)."""
    trial = model.copy()
    trial.components[i].values = {"v": np.array(int(trial.components[i].values["v"]) + 1)}
    return trial.nll() - 0.5 * (i == 0), trial.nuisance.values, \
        [c.values for c in trial.components]


def _toy_backfit(model, i, maxiter):
    """The component moves to the end as a new effect with its number + 1."""
    trial = model.copy()
    old = trial.components[i]
    trial.remove(old)
    new = Component(effect=_Eff(old.effect.name + "'"), specs={},
                    values={"v": np.array(int(old.values["v"]) + 1)})
    trial.components.append(new)
    return (trial.nll(), trial.nuisance.values, [c.values for c in trial.components],
            new.effect, new.specs)


def _one_by_one(model, plan, best, tasks):
    """The reference: each planned trial in turn, from what the kept ones left."""
    tried = []
    for kind, eff in plan:
        i = _effect_position(model, eff)
        r = tasks[kind](model, i, 0)
        tried.append(eff)
        if r[0] < best - 1e-6:
            _keep(model, kind, i, r)
            best = r[0]
    return best, tried


def test_03_speculative_trials_keep_what_trying_them_one_by_one_keeps(monkeypatch):
    """Restarts and backfits as one sequence: the pool's speculation ends as the
    one-by-one reference, for pools of 1, 2, 3 and 10 processes; every planned
    effect is tried once although kept backfits move effects to the end."""
    tasks = {"restart": _toy_restart, "backfit": _toy_backfit}
    monkeypatch.setattr(adoption, "_TRIALS", tasks)
    start = [1, 4, 3, 5, 8, 7]

    def plan_of(m):
        c = m.components
        return ([("restart", c[0].effect), ("restart", c[3].effect)]
                + [("backfit", x.effect) for k, x in enumerate(c) if k != 1])

    ref = _Toy(start)
    plan = plan_of(ref)
    best, tried = _one_by_one(ref, plan, ref.nll(), tasks)
    assert tried == [e for _, e in plan]                     # each planned trial once
    assert ref.numbers() != start and best < _Toy(start).nll() - 2   # several kept
    for width in (1, 2, 3, 10):                     # processes ahead of the reader
        pool = _Batches(width)
        spec = _Toy(start)
        got = _in_order(spec, plan_of(spec), spec.nll(), 0, pool)
        assert spec.numbers() == ref.numbers() and got == best
        assert [c.effect.name for c in spec.components] == [c.effect.name for c in ref.components]
        if width == 1:                                      # nothing run in vain
            assert sum(pool.batches) == len(plan)


class _Batches:
    """A serial stand-in for a pool of ``workers`` processes: ``first`` runs
    ``workers`` tasks ahead of the one it reads (what runs in vain on
    processes) and records how many tasks each call ran."""

    def __init__(self, workers):
        self.workers, self.batches = workers, []

    def first(self, fn, shared, tasks, accept):
        results = []
        for i, t in enumerate(tasks):
            results += [fn(shared, *u) for u in tasks[len(results):i + self.workers]]
            if accept(results[i]):
                self.batches.append(len(results))
                return i, results[i]
        self.batches.append(len(results))
        return None


def test_03b_first_accepted_task_on_processes_and_here():
    """``FitPool.first`` returns the first accepted task in order, on two
    processes as in this process, and None when none is accepted."""
    import operator

    for pool in (FitPool(1), FitPool(2)):
        assert pool.first(operator.pow, 2, [(k,) for k in range(6)], lambda r: r >= 8) == (3, 8)
        assert pool.first(operator.pow, 2, [(k,) for k in range(4)], lambda r: r > 100) is None


def _measured_and_base():
    radar = RadarConfig.awr1843(num_chirps=2, num_samples=64)
    T, R = radar.num_tx, radar.num_rx
    rng = np.random.default_rng(4)
    g = np.exp(1j * (rng.uniform(-np.pi, np.pi, T)[:, None] + rng.uniform(-np.pi, np.pi, R)[None]))

    base = [(1.5, 0.0, 1.0), (3.4, np.radians(-20), 0.5)]
    clean = point_targets_adc(radar, base)
    meas = point_targets_adc(radar, base + [(2.6, np.radians(25), 0.4)]) * g[None, :, :, None, None]
    meas = meas + 0.01 * (rng.normal(size=clean.shape) + 1j * rng.normal(size=clean.shape))
    return EffectContext(radar), meas, clean


def test_04_a_pickled_model_computes_what_the_original_computes():
    ctx, meas, clean = _measured_and_base()
    m = EffectModel(ctx, meas, clean)
    m.add(ChannelGain())
    m.fit(maxiter=20)
    again = pickle.loads(pickle.dumps(m))
    assert "Y" not in m.__getstate__()                       # tensors are rebuilt, not sent
    assert np.array_equal(again.mean_variance_numpy()[0], m.mean_variance_numpy()[0])
    assert again.nll() == m.nll()


def test_05_diagnosis_on_two_processes_is_the_diagnosis_on_one():
    """Every candidate score, the adoptions (with the backfit of the first
    adopted effect) and the final metrics are the same numbers."""
    ctx, meas, clean = _measured_and_base()
    cands = [ChannelGain(), MissingScatterer(), NoiseFloor()]
    one = diagnose(EffectModel(ctx, meas, clean), cands, max_rounds=2, workers=1)
    two = diagnose(EffectModel(ctx, meas, clean), cands, max_rounds=2, workers=2)
    assert one.adopted == two.adopted == ["channel_gain", "missing_scatterer"]
    for a, b in zip(one.adoptions, two.adoptions):
        def scores(cands):                                   # all but the fits' seconds
            return [{k: v for k, v in c.to_dict().items() if k != "fit_s"} for c in cands]

        assert scores(a.candidates) == scores(b.candidates)
        assert a.after == b.after
    assert one.final == two.final


_ORPHAN_SCRIPT = """
import os, sys
from sionna_mmir.residual.workers import FitPool

def pid(shared, k):
    return os.getpid()

if __name__ == "__main__":
    print(*sorted(set(FitPool(2).map(pid, None, [(k,) for k in range(8)]))), flush=True)
    sys.stdin.read()                       # wait to be killed
"""


def test_07b_a_worker_started_after_its_loop_died_exits():
    """The watcher follows the loop's process id, given by the loop: a worker
    that starts after the loop is gone (it is then a child of init) exits
    at once instead of waiting for work forever."""
    import subprocess
    import sys

    code = ("import os; from sionna_mmir.residual.workers import _exit_with_parent; "
            "_exit_with_parent(os.getppid() + 1234567, period=0.05); print('still here')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0 and "still here" not in out.stdout


def test_07_workers_exit_when_their_loop_is_killed(tmp_path):
    """A loop killed outright (SIGKILL: no clean-up runs) leaves no worker behind."""
    import signal
    import subprocess
    import sys
    import time

    script = tmp_path / "loop.py"
    script.write_text(_ORPHAN_SCRIPT)
    proc = subprocess.Popen([sys.executable, str(script)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    pids = [int(p) for p in proc.stdout.readline().split()]
    assert pids and proc.pid not in pids
    proc.send_signal(signal.SIGKILL)
    proc.wait()

    def alive(pid):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        return True

    deadline = time.time() + 20
    while any(alive(p) for p in pids) and time.time() < deadline:
        time.sleep(0.2)
    assert not any(alive(p) for p in pids)
