"""Path-solver benchmark: sionna_mmir's ``RadarPathSolver`` vs Sionna RT's ``PathSolver``.

Both solvers run in the same invocation on the same LiDAR-like room mesh
(:func:`lidar_mesh.lidar_room_mesh`: floor, walls, boxes, mm vertex jitter,
small holes; one object, concrete), the same radar (``RadarConfig.mmwcas()``:
12 Tx x 16 Rx = 192 pairs, at the origin looking along ``+x``), the same
number of rays ``N`` (Sionna: ``samples_per_src=N`` from its one source) and
the same ``max_depth``.

sionna_mmir
    ``RadarPathSolver()(scene, radar, num_rays=N, max_depth=D, seed=0)``,
    isotropic elements (``tx_pattern=rx_pattern="iso"``, as on the Sionna
    side).  One path per hit ray and depth, held factorised over the
    elements (``a = c g_t g_r``, ``tau = tau_t + tau_r``: ``RadarPaths.factors``)
    and synthesised without the ``[T, R, P]`` expansion.
    Gradients: ``vertex_materials`` [Nv, 6] and ``vertex_normals`` [Nv, 3] of
    the mesh object.
Sionna RT 2.2
    ``PathSolver`` with ``loop_mode = "evaluated"`` (``"symbolic"``, Sionna's
    default, cannot be differentiated), ``specular_reflection`` and
    ``diffuse_reflection`` on, ``refraction``/``diffraction``/``los`` off (Tx
    and Rx share one point: the radar is monostatic), ``synthetic_array=True``
    (Sionna's default and cheapest: paths are traced once from the array
    centre and the 192 pairs get per-element phase shifts -- the same MIMO
    ray reuse as sionna_mmir).  One ``Transmitter`` and one ``Receiver`` at
    the cascade's array centre, each with an ``AntennaArray`` holding the 12
    Tx / 16 Rx element offsets (isotropic, V-polarised).  Material:
    ``ITURadioMaterial("concrete", thickness=0.2, scattering_coefficient=0.7)``
    (Lambertian diffuse lobe; ``S^2 = 0.5`` of the reflected energy diffuse),
    ``scene.frequency = 77 GHz``.  Gradients: the material's
    ``relative_permittivity``, ``conductivity`` and ``scattering_coefficient``
    (three scalars: Sionna detaches the path geometry, so these are what it
    can differentiate).  A forward in ``"symbolic"`` mode is timed too.

Measured stages (each: a warm-up run, then the best of ``repeat`` runs; the
first, cold run -- Dr.Jit kernel compilation, unless the on-disk kernel cache
has them -- is recorded as ``cold_s``):

``fwd_paths``   solver + evaluate the paths (sionna_mmir: the factors
                ``c [P]``, ``g_t, tau_t [T P]``, ``g_r, tau_r [R P]``, from
                which every per-pair amplitude and delay follows by one product;
                Sionna: ``paths.a`` with the synthetic array applied)
``fb_paths``    the same, loss ``sum |a|^2`` over pairs and paths (sionna_mmir:
                ``sum_p |c|^2 sum_t g_t^2 sum_r g_r^2``, the same number),
                ``dr.backward``, evaluate the gradients
``fwd_signal``  sionna_mmir: solver + ``paths.adc(radar)`` (raw ADC, 256
                samples); Sionna: solver + ``paths.cfr`` at the 256 ADC
                sample frequencies ``f0 + S t_k`` (its counterpart of the ADC)
``fb_signal``   the same, loss ``sum |ADC|^2`` (``sum |CFR|^2``), backward,
                evaluate the gradients

Every (mesh, rays, solver) runs in its own subprocess; before each stage the
Dr.Jit allocation cache is flushed and the peak-RSS counter is reset
(``/proc/self/clear_refs``), so each stage reports its own peak (``VmHWM``,
the process's baseline -- interpreter, scene -- included).  A background
thread also samples the worker's RSS (``/proc/self/statm``) and the system's
``MemAvailable`` every 10 ms during the stage (``peak_sampled_gib``,
``memavail_drop_gib``), and Dr.Jit's own allocation watermark is recorded
(``drjit_watermark_gib``, ``dr.detail.malloc_watermark``).  The parent kills
a worker whose RSS passes ``--mem-limit-gib`` and records the stage as
``killed``.

What runs by default, ``--quick`` and ``--full-signal``: see :func:`plan`.
Timings on a shared machine are noisy: the load average at start and end is
recorded beside them.

Run:  python benchmarks/bench_paths.py [--quick | --full-signal] [--out results.json]
          [--blas-threads N] [--mem-limit-gib G] [--no-memory-check] [--depth D]
          [--triangles 1e5,1e6 --rays 1e4,1e5 [--signal] [--repeat N]] [--rounds R]
"""
from __future__ import annotations

import argparse
import gc
import json
import os
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)

GIB = 2.0 ** 30
MARK = "@@BENCH "

#: material of the Sionna side (see the module docstring)
SIONNA_SCATTERING = 0.7
SIONNA_THICKNESS = 0.2


# --------------------------------------------------------------------------- plan
def plan(quick: bool = False, depth: int = 3, memory_check: bool = True, full_signal: bool = False,
         triangles=None, rays=None, signal: bool = False, repeat: int | None = None):
    """List of jobs ``dict(triangles, rays, depth, solver, stages, repeat, warmup)``.

    ``triangles`` / ``rays`` (sequences): a custom grid instead -- every
    (triangles, rays) pair, the paths stages only (all four with ``signal``),
    ``repeat`` timed runs per stage (default 2), no memory check.

    Default (about 6-8 minutes on 2 cores): the headline at 100k triangles /
    1e4 rays (all four stages); triangles 1e4 and 1e6 at 1e4 rays and 1e5 rays
    at 100k triangles (paths level: the signal stages do not depend on the
    mesh, and at 1e5 rays they take minutes); 1e3 rays at 100k triangles (all
    stages); the memory check (1M triangles, 1e6 rays, one cold run:
    sionna_mmir paths level and with the ADC, Sionna paths level).
    ``full_signal``: the signal stages everywhere (about 15 minutes).
    ``quick``: 10k triangles, 1e3 rays, all stages, no memory check.
    """
    both = ("fwd_paths", "fb_paths", "fwd_signal", "fb_signal")
    paths = both[:2]
    if triangles or rays:
        cfgs = [(int(t), int(r), both if signal else paths, int(repeat or 2))
                for t in (triangles or [100_000]) for r in (rays or [10_000])]
        memory_check = False
    elif quick:
        cfgs = [(10_000, 1_000, both, 2)]
        memory_check = False
    else:
        cfgs = [
            (100_000, 10_000, both, 2),          # headline
            (10_000, 10_000, both if full_signal else paths, 2),
            (1_000_000, 10_000, both if full_signal else paths, 2),
            (100_000, 1_000, both, 2),
            # 1e5 rays: the signal stages take about a minute per run
            (100_000, 100_000, both if full_signal else paths, 1 if full_signal else 2),
        ]
    jobs = []
    for tri, rays, stages, rep in cfgs:
        for solver in ("mmir", "sionna"):
            st = list(stages) + (["fwd_paths_symbolic"] if solver == "sionna" else [])
            jobs.append(dict(triangles=tri, rays=rays, depth=depth, solver=solver,
                             stages=st, repeat=rep, warmup=True))
    if memory_check:
        # one cold run per stage (a warm-up would double the time)
        jobs.append(dict(triangles=1_000_000, rays=1_000_000, depth=depth, solver="mmir",
                         stages=["fb_paths", "fb_signal"], repeat=1, warmup=False, memory_check=True))
        jobs.append(dict(triangles=1_000_000, rays=1_000_000, depth=depth, solver="sionna",
                         stages=["fb_paths"], repeat=1, warmup=False, memory_check=True))
    return jobs


# ------------------------------------------------------------------------- worker
def _status(key):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    return 0


def _reset_peak():
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _mem_available():
    with open("/proc/meminfo") as f:
        for line in f:
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    return 0


class MemSampler:
    """Background thread sampling this process's RSS and the system's
    ``MemAvailable`` every ``interval`` s: ``peak_rss`` and ``avail_drop`` [bytes]
    (the latter also counts other processes' growth: an upper bound)."""

    def __init__(self, interval=0.01):
        self.interval = interval
        self.page = os.sysconf("SC_PAGE_SIZE")
        self.peak_rss, self.avail0, self.min_avail = 0, _mem_available(), None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _sample(self):
        with open("/proc/self/statm") as f:
            rss = int(f.read().split()[1]) * self.page
        self.peak_rss = max(self.peak_rss, rss)
        avail = _mem_available()
        self.min_avail = avail if self.min_avail is None else min(self.min_avail, avail)

    def _run(self):
        while not self._stop.is_set():
            self._sample()
            time.sleep(self.interval)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self._sample()

    @property
    def avail_drop(self):
        return max(0, self.avail0 - (self.min_avail or self.avail0))


def _drjit_watermark():
    import drjit as dr

    try:
        return dr.detail.malloc_watermark(dr.JitBackend.LLVM)
    except (AttributeError, TypeError):
        return None


def _drjit_clear_stats():
    import drjit as dr

    try:
        dr.detail.malloc_clear_statistics()
    except AttributeError:
        pass


def _emit(obj):
    sys.stdout.write(MARK + json.dumps(obj) + "\n")
    sys.stdout.flush()


class Timers:
    """Accumulating named timers (seconds) for one run."""

    def __init__(self):
        self.t = {}

    def add(self, key, dt):
        self.t[key] = self.t.get(key, 0.0) + dt


def _sync():
    import drjit as dr

    dr.sync_thread()
    return time.perf_counter()


def _instrument_adc(timers_ref):
    """Time the NumPy ADC synthesis and its adjoint inside the custom ops."""
    from sionna_mmir.fmcw import synthesize as syn
    from sionna_mmir.fmcw import synthesize_factorised as fac

    _wrap_adc(syn._Prepared, timers_ref)
    _wrap_adc(fac.FactorisedSynthesis, timers_ref)


def _wrap_adc(cls, timers_ref):
    if getattr(cls, "_bench_wrapped", False):
        return
    fwd, vjp = cls.forward, cls.vjp

    def forward(self):
        t = time.perf_counter()
        out = fwd(self)
        timers_ref[0].add("adc_numpy_forward", time.perf_counter() - t)
        return out

    def vjp_(self, G):
        t = time.perf_counter()
        out = vjp(self, G)
        timers_ref[0].add("adc_numpy_adjoint", time.perf_counter() - t)
        return out

    cls.forward, cls.vjp = forward, vjp_
    cls._bench_wrapped = True


class MMIRCase:
    """sionna_mmir side of one (mesh, rays) configuration."""

    def __init__(self, mesh, rays, depth):
        import sionna_mmir  # noqa: F401  (backend first)
        from sionna_mmir import RadarConfig
        from sionna_mmir.scene import load_scene

        self.radar = RadarConfig.mmwcas()
        self.scene = load_scene({"room": mesh}, materials={"room": "concrete"}, radar=self.radar)
        self.obj = self.scene.mesh_objects["room"]
        self.rays, self.depth = rays, depth
        self.timers = [Timers()]
        _instrument_adc(self.timers)
        self.info = {}

    def _solve(self):
        from sionna_mmir.paths import RadarPathSolver

        T = self.timers[0]
        t = _sync()
        paths = RadarPathSolver()(self.scene, self.radar, num_rays=self.rays, max_depth=self.depth,
                                  seed=0, tx_pattern="iso", rx_pattern="iso")
        t1 = _sync()
        T.add("solver_call", t1 - t)
        self.info = dict(paths=int(paths.num_paths), hits=int(paths.info.get("hits", 0)),
                         pair_paths=int(paths.shape[0] * paths.shape[1] * paths.shape[2]))
        return paths

    def _eval_paths(self, paths):
        import drjit as dr

        t = _sync()
        dr.eval(*paths.arrays())          # the factors (no [T, R, P] expansion)
        self.timers[0].add("eval_paths", _sync() - t)

    def _adc(self, paths):
        import drjit as dr

        t = _sync()
        adc = paths.adc(self.radar)
        dr.eval(adc.real, adc.imag)
        self.timers[0].add("adc_total", _sync() - t)
        return adc

    def run(self, stage):
        import drjit as dr

        grad = stage.startswith("fb")
        params = (self.obj.vertex_materials, self.obj.vertex_normals)
        if grad:
            for p in params:
                dr.enable_grad(p)
        try:
            paths = self._solve()
            self._eval_paths(paths)
            if stage.endswith("signal"):
                adc = self._adc(paths)
                loss = dr.sum(dr.square(adc.real.array) + dr.square(adc.imag.array))
            else:
                loss = paths.power()
            t = _sync()
            dr.eval(loss)
            self.timers[0].add("loss", _sync() - t)
            if grad:
                t = _sync()
                dr.backward(loss)
                g = [dr.grad(p) for p in params]
                dr.eval(g)
                self.timers[0].add("backward", _sync() - t)
                self.info["grad_abs_sum"] = float(sum(float(dr.sum(dr.abs(x.array))[0]) for x in g))
            self.info["loss"] = float(dr.detach(loss)[0])
        finally:
            if grad:
                for p in params:
                    dr.disable_grad(p)


class SionnaCase:
    """Sionna RT side of one (mesh, rays) configuration."""

    def __init__(self, mesh, rays, depth, tmpdir):
        import sionna_mmir  # noqa: F401  (backend first)
        import drjit as dr
        import mitsuba as mi
        import numpy as np
        import sionna.rt as rt
        from sionna_mmir import RadarConfig

        self.radar = radar = RadarConfig.mmwcas()
        ply = os.path.join(tmpdir, "room.ply")
        mesh.export(ply)
        scene = rt.load_scene()
        scene.frequency = radar.start_frequency
        self.mat = rt.ITURadioMaterial("concrete", "concrete", thickness=SIONNA_THICKNESS,
                                       scattering_coefficient=SIONNA_SCATTERING)
        scene.edit(add=rt.SceneObject(fname=ply, name="room", radio_material=self.mat))
        c = np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0)
        lam = float(dr.detach(scene.wavelength)[0])
        pattern = rt.antenna_pattern.antenna_pattern_registry.get("iso")(polarization="V")

        def array(pos):
            q = ((pos - c) / lam).astype(np.float32)
            return rt.AntennaArray(pattern, mi.Point3f(q[:, 0], q[:, 1], q[:, 2]))

        scene.tx_array = array(radar.tx_positions)
        scene.rx_array = array(radar.rx_positions)
        centre = mi.Point3f(*(float(x) + float(p) for x, p in zip(c, radar.position)))
        scene.add(rt.Transmitter("radar_tx", position=centre, orientation=mi.Point3f(0, 0, 0)))
        scene.add(rt.Receiver("radar_rx", position=centre, orientation=mi.Point3f(0, 0, 0)))
        self.scene = scene
        self.solver = rt.PathSolver()
        self.solver.loop_mode = "evaluated"
        self.solver_sym = rt.PathSolver()
        self.solver_sym.loop_mode = "symbolic"
        self.kw = dict(max_depth=depth, samples_per_src=int(rays),
                       max_num_paths_per_src=max(1000, int(rays) * depth), los=False,
                       specular_reflection=True, diffuse_reflection=True, refraction=False,
                       diffraction=False, synthetic_array=True, seed=0)
        self.freqs = mi.Float((radar.start_frequency + radar.slope * radar.sample_times()).astype(np.float32))
        self.timers = [Timers()]
        self.info = {}

    def run(self, stage):
        import drjit as dr

        T = self.timers[0]
        grad = stage.startswith("fb")
        params = (self.mat.relative_permittivity, self.mat.conductivity, self.mat.scattering_coefficient)
        if grad:
            for p in params:
                dr.enable_grad(p)
        try:
            solver = self.solver_sym if stage.endswith("symbolic") else self.solver
            t = _sync()
            paths = solver(self.scene, **self.kw)
            t1 = _sync()
            T.add("solver_call", t1 - t)
            if stage.endswith("signal"):
                re, im = paths.cfr(self.freqs, normalize_delays=False)
                loss = dr.sum(dr.square(re.array) + dr.square(im.array))
                dr.eval(loss)
                T.add("cfr_and_loss", _sync() - t1)
            else:
                re, im = paths.a
                dr.eval(re, im)
                t2 = _sync()
                T.add("eval_a", t2 - t1)
                loss = dr.sum(dr.square(re.array) + dr.square(im.array))
                dr.eval(loss)
                T.add("loss", _sync() - t2)
            n_paths = int(dr.shape(paths.a[0])[-1])
            self.info = dict(paths=n_paths, pair_paths=self.radar.num_tx * self.radar.num_rx * n_paths)
            if grad:
                t = _sync()
                dr.backward(loss)
                g = [dr.grad(p) for p in params]
                dr.eval(g)
                T.add("backward", _sync() - t)
                self.info["grad"] = [float(x[0]) for x in g]
            self.info["loss"] = float(dr.detach(loss)[0])
        finally:
            if grad:
                for p in params:
                    dr.disable_grad(p)


def worker(job):
    """Run one job's stages, emitting one JSON line per stage start / result."""
    t0 = time.perf_counter()
    import sionna_mmir

    sionna_mmir.init_backend()
    import drjit as dr
    from lidar_mesh import lidar_room_mesh

    mesh = lidar_room_mesh(job["triangles"], seed=0)
    with tempfile.TemporaryDirectory() as tmp:
        if job["solver"] == "mmir":
            case = MMIRCase(mesh, job["rays"], job["depth"])
        else:
            case = SionnaCase(mesh, job["rays"], job["depth"], tmp)
        _emit(dict(event="setup", setup_s=time.perf_counter() - t0, triangles=int(len(mesh.faces)),
                   vertices=int(len(mesh.vertices)), rss_gib=_status("VmRSS") / GIB))
        for stage in job["stages"]:
            gc.collect()
            dr.flush_malloc_cache()
            base = _status("VmRSS")
            reset = _reset_peak()
            _drjit_clear_stats()
            _emit(dict(event="start", stage=stage))
            times, breakdown, cold = [], [], None
            runs = int(job["repeat"]) + (1 if job.get("warmup", True) else 0)
            with MemSampler() as mem:
                for i in range(max(1, runs)):
                    case.timers[0] = Timers()
                    t = _sync()
                    case.run(stage)
                    dt = _sync() - t
                    if i == 0:
                        cold = dt
                    if i > 0 or not job.get("warmup", True):
                        times.append(dt)
                        breakdown.append(dict(case.timers[0].t))
            best = min(range(len(times)), key=lambda k: times[k])
            wm = _drjit_watermark()
            _emit(dict(event="result", stage=stage, status="ok", best_s=times[best], times_s=times,
                       cold_s=cold, breakdown=breakdown[best], info=dict(case.info),
                       peak_gib=_status("VmHWM") / GIB, base_gib=base / GIB,
                       peak_sampled_gib=mem.peak_rss / GIB, memavail_drop_gib=mem.avail_drop / GIB,
                       drjit_watermark_gib=None if wm is None else wm / GIB,
                       peak_is_per_stage=reset))


# ------------------------------------------------------------------------- parent
def _run_job(job, mem_limit_gib, python=sys.executable, log=None, blas_threads=None):
    """Run one job in a subprocess with an RSS watchdog; returns a result dict."""
    cmd = [python, os.path.abspath(__file__), "--worker", json.dumps(job)]
    env = dict(os.environ)
    if blas_threads:
        env["OPENBLAS_NUM_THREADS"] = env["OMP_NUM_THREADS"] = str(int(blas_threads))
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=HERE, env=env)
    out = dict(job=job, setup=None, stages={}, error=None)
    state = dict(current=None, max_rss=0.0, killed=False)
    err_lines = []

    def read_out():
        for line in proc.stdout:
            if not line.startswith(MARK):
                continue
            ev = json.loads(line[len(MARK):])
            if ev["event"] == "setup":
                out["setup"] = ev
            elif ev["event"] == "start":
                state["current"] = ev["stage"]
            elif ev["event"] == "result":
                out["stages"][ev["stage"]] = ev
                state["current"] = None
                if log:
                    log(job, ev)

    def read_err():
        for line in proc.stderr:
            err_lines.append(line)
            del err_lines[:-40]

    threads = [threading.Thread(target=read_out, daemon=True), threading.Thread(target=read_err, daemon=True)]
    for th in threads:
        th.start()
    limit = mem_limit_gib * GIB
    while proc.poll() is None:
        try:
            with open(f"/proc/{proc.pid}/status") as f:
                rss = next((int(line.split()[1]) * 1024 for line in f if line.startswith("VmRSS:")), 0)
        except OSError:
            rss = 0
        state["max_rss"] = max(state["max_rss"], rss)
        if rss > limit:
            state["killed"] = True
            proc.kill()
            break
        time.sleep(0.05)
    proc.wait()
    for th in threads:
        th.join(timeout=5)
    if state["killed"]:
        stage = state["current"] or "setup"
        out["stages"][stage] = dict(event="result", stage=stage, status="killed",
                                    peak_gib=state["max_rss"] / GIB,
                                    note=f"RSS passed the {mem_limit_gib:g} GiB limit; worker killed")
        if log:
            log(job, out["stages"][stage])
    elif proc.returncode != 0:
        stage = state["current"] or "setup"
        out["error"] = "".join(err_lines[-15:])
        out["stages"].setdefault(stage, dict(event="result", stage=stage, status="error",
                                             note=out["error"].strip().splitlines()[-1:]))
    return out


def _default_mem_limit():
    try:
        with open("/proc/meminfo") as f:
            avail = next(int(line.split()[1]) * 1024 for line in f if line.startswith("MemAvailable:"))
        return min(20.0, 0.8 * avail / GIB)
    except (OSError, StopIteration):
        return 16.0


def run(quick=False, depth=3, mem_limit_gib=None, memory_check=True, log=None, blas_threads=None,
        full_signal=False, triangles=None, rays=None, signal=False, repeat=None, rounds=1):
    """Run the plan; returns ``dict(meta, jobs, rows, ratios, breakdown, memory, round_ratios)``.

    ``blas_threads`` sets ``OPENBLAS_NUM_THREADS`` in the workers (default:
    the environment's; the ADC adjoint's small batched complex products are
    very sensitive to it when the cores are shared).  ``triangles``, ``rays``,
    ``signal``, ``repeat``: a custom grid (see :func:`plan`).  ``rounds``:
    run the whole plan that many times, one job after the other (the two
    solvers of a configuration back to back in every round), and keep each
    stage's best over the rounds; ``round_ratios`` lists the ratio of every
    round (the two solvers measured minutes, not hours, apart).
    """
    import platform

    mem_limit_gib = mem_limit_gib or _default_mem_limit()
    t0 = time.perf_counter()
    load0 = os.getloadavg()
    jobs_plan = plan(quick, depth, memory_check, full_signal, triangles, rays, signal, repeat)
    raw, loads = [], []
    for rnd in range(max(1, int(rounds))):
        loads.append(os.getloadavg())
        for j in jobs_plan:
            out = _run_job(j, mem_limit_gib, log=log, blas_threads=blas_threads)
            out["round"] = rnd
            raw.append(out)
    loads.append(os.getloadavg())
    jobs = _merge_rounds(raw) if rounds > 1 else raw
    res = dict(meta=dict(quick=quick, full_signal=full_signal, depth=depth, mem_limit_gib=mem_limit_gib,
                         cpu_count=os.cpu_count(), machine=platform.machine(),
                         blas_threads=blas_threads or os.environ.get("OPENBLAS_NUM_THREADS"),
                         loadavg_start=load0, loadavg_end=os.getloadavg(), loadavg_rounds=loads,
                         rounds=int(rounds), total_s=time.perf_counter() - t0),
               jobs=jobs)
    res.update(summarise(jobs))
    res["round_ratios"] = _round_ratios(raw)
    return res


def _job_key(jb):
    return (jb["triangles"], jb["rays"], jb["depth"], jb["solver"], bool(jb.get("memory_check")))


def _merge_rounds(raw):
    """One result per job: each stage's best round (``rounds_best_s``: every round's best)."""
    merged = {}
    for out in raw:
        k = _job_key(out["job"])
        m = merged.setdefault(k, dict(job=out["job"], setup=out["setup"], stages={}, error=out["error"]))
        m["setup"] = m["setup"] or out["setup"]
        for st, ev in out["stages"].items():
            cur = m["stages"].get(st)
            per = (cur or {}).get("rounds_best_s", []) + [ev.get("best_s") if ev.get("status") == "ok"
                                                         else None]
            better = cur is None or (ev.get("status") == "ok" and
                                     (cur.get("status") != "ok" or ev["best_s"] < cur["best_s"]))
            m["stages"][st] = dict(ev if better else cur, rounds_best_s=per)
    return list(merged.values())


def _round_ratios(raw):
    """``[dict(triangles, rays, stage, round, ours_s, sionna_s, ratio)]`` per round."""
    by = {}
    for out in raw:
        jb = out["job"]
        if jb.get("memory_check"):
            continue
        by[(out.get("round", 0), jb["triangles"], jb["rays"], jb["solver"])] = out
    rows = []
    for (rnd, tri, rays, solver), m in sorted(by.items()):
        s = by.get((rnd, tri, rays, "sionna"))
        if solver != "mmir" or s is None:
            continue
        for st in ("fwd_paths", "fb_paths", "fwd_signal", "fb_signal"):
            a, b = _get(m, st), _get(s, st)
            if a is not None and b:
                rows.append(dict(triangles=tri, rays=rays, stage=st, round=rnd, ours_s=a, sionna_s=b,
                                 ratio=a / b))
    return rows


def _get(job, stage, key="best_s"):
    s = job["stages"].get(stage)
    if not s or s.get("status") != "ok":
        return None
    return s.get(key)


def _le(x, limit):
    return None if x is None else bool(x <= limit)


def summarise(jobs):
    """Rows per (triangles, rays, solver), ratios per (triangles, rays)."""
    rows, by = [], {}
    for j in jobs:
        jb = j["job"]
        if jb.get("memory_check"):
            continue
        info = next((s.get("info", {}) for s in j["stages"].values() if s.get("status") == "ok"), {})
        row = dict(triangles=jb["triangles"], rays=jb["rays"], depth=jb["depth"], solver=jb["solver"],
                   mesh_triangles=(j["setup"] or {}).get("triangles"), paths=info.get("paths"),
                   pair_paths=info.get("pair_paths"))
        for st in ("fwd_paths", "fb_paths", "fwd_signal", "fb_signal", "fwd_paths_symbolic"):
            row[st + "_s"] = _get(j, st)
            row[st + "_peak_gib"] = _get(j, st, "peak_gib")
            s = j["stages"].get(st)
            row[st + "_status"] = None if s is None else s.get("status")
        rows.append(row)
        by[(jb["triangles"], jb["rays"], jb["solver"])] = row
    ratios = []
    for (tri, rays, solver), m in by.items():
        if solver != "mmir" or (tri, rays, "sionna") not in by:
            continue
        s = by[(tri, rays, "sionna")]

        def rt(a, b):
            return None if a is None or b is None or b == 0 else a / b
        ratios.append(dict(triangles=tri, rays=rays,
                           fwd_paths=rt(m["fwd_paths_s"], s["fwd_paths_s"]),
                           fb_paths=rt(m["fb_paths_s"], s["fb_paths_s"]),
                           fwd_signal=rt(m["fwd_signal_s"], s["fwd_signal_s"]),
                           fb_signal=rt(m["fb_signal_s"], s["fb_signal_s"]),
                           fb_adc_vs_sionna_paths=rt(m["fb_signal_s"], s["fb_paths_s"]),
                           fb_paths_per_pair_path=rt(rt(m["fb_paths_s"], m["pair_paths"]),
                                                     rt(s["fb_paths_s"], s["pair_paths"])),
                           target_fb_le_0_5=_le(rt(m["fb_paths_s"], s["fb_paths_s"]), 0.5),
                           target_fb_signal_le_0_5=_le(rt(m["fb_signal_s"], s["fb_signal_s"]), 0.5)))
    breakdown = []
    for j in jobs:
        jb = j["job"]
        for st, s in j["stages"].items():
            if s.get("status") == "ok":
                breakdown.append(dict(triangles=jb["triangles"], rays=jb["rays"], solver=jb["solver"],
                                      stage=st, best_s=s["best_s"], cold_s=s.get("cold_s"),
                                      **{k: v for k, v in s.get("breakdown", {}).items()}))
    memory = []
    for j in jobs:
        jb = j["job"]
        if not jb.get("memory_check"):
            continue
        for st, s in j["stages"].items():
            memory.append(dict(triangles=jb["triangles"], rays=jb["rays"], solver=jb["solver"], stage=st,
                               status=s.get("status"), time_s=s.get("best_s"),
                               peak_gib=s.get("peak_gib"), base_gib=s.get("base_gib"),
                               peak_sampled_gib=s.get("peak_sampled_gib"),
                               memavail_drop_gib=s.get("memavail_drop_gib"),
                               drjit_watermark_gib=s.get("drjit_watermark_gib"),
                               paths=s.get("info", {}).get("paths"),
                               pair_paths=s.get("info", {}).get("pair_paths"),
                               breakdown=s.get("breakdown"), note=s.get("note")))
    return dict(rows=rows, ratios=ratios, breakdown=breakdown, memory=memory)


# ----------------------------------------------------------------------- markdown
def _f(x, fmt="{:.3f}"):
    return "-" if x is None else fmt.format(x)


def to_markdown(res):
    name = {"mmir": "sionna_mmir", "sionna": "Sionna RT"}
    meta = res["meta"]
    out = [f"Depth {meta['depth']}, mmwcas (12 Tx x 16 Rx), times in s (best of runs after a warm-up), "
           f"peak RSS in GiB per stage; {meta['cpu_count']} CPU cores, LLVM backend, "
           f"OPENBLAS_NUM_THREADS={meta['blas_threads'] or 'default'}, load average "
           f"{meta['loadavg_start'][0]:.1f} at start / {meta['loadavg_end'][0]:.1f} at end.", "",
           "| triangles | rays | solver | paths | fwd paths | fwd+bwd paths | fwd signal | fwd+bwd signal "
           "| peak fwd+bwd paths | peak fwd+bwd signal | Sionna fwd (symbolic) |",
           "|---:|---:|:---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in sorted(res["rows"], key=lambda r: (r["rays"], r["triangles"], r["solver"])):
        out.append(f"| {r['mesh_triangles'] or r['triangles']:,} | {r['rays']:.0e} | {name[r['solver']]} | "
                   f"{_f(r['paths'], '{:,}')} | {_f(r['fwd_paths_s'])} | {_f(r['fb_paths_s'])} | "
                   f"{_f(r['fwd_signal_s'])} | {_f(r['fb_signal_s'])} | {_f(r['fb_paths_peak_gib'], '{:.2f}')} | "
                   f"{_f(r['fb_signal_peak_gib'], '{:.2f}')} | {_f(r['fwd_paths_symbolic_s'])} |")
    out += ["", "Signal: sionna_mmir = raw ADC (`paths.adc`, 256 samples); Sionna = `paths.cfr` at the 256 "
            "ADC frequencies.", "",
            "| triangles | rays | mmIR/Sionna fwd paths | fwd+bwd paths | fwd signal | fwd+bwd signal "
            "| mmIR ADC fwd+bwd / Sionna paths fwd+bwd | per pair-path fwd+bwd | target fwd+bwd <= 0.5 "
            "(paths / signal) |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|:---:|"]
    for r in sorted(res["ratios"], key=lambda r: (r["rays"], r["triangles"])):
        ok = " / ".join("-" if r[k] is None else ("met" if r[k] else "missed")
                        for k in ("target_fb_le_0_5", "target_fb_signal_le_0_5"))
        out.append(f"| {r['triangles']:,} | {r['rays']:.0e} | {_f(r['fwd_paths'], '{:.2f}')} | "
                   f"{_f(r['fb_paths'], '{:.2f}')} | {_f(r['fwd_signal'], '{:.2f}')} | "
                   f"{_f(r['fb_signal'], '{:.2f}')} | {_f(r['fb_adc_vs_sionna_paths'], '{:.1f}')} | "
                   f"{_f(r['fb_paths_per_pair_path'], '{:.2f}')} | {ok} |")
    keys = ("solver_call", "eval_paths", "eval_a", "adc_total", "adc_numpy_forward", "cfr_and_loss",
            "loss", "backward", "adc_numpy_adjoint")
    bd = [b for b in res["breakdown"] if b["stage"].startswith("fb")]
    if bd:
        out += ["", "Stage breakdown of the fwd+bwd runs [s] (`adc_numpy_*` are inside `adc_total` / "
                "`backward`):", "",
                "| triangles | rays | solver | stage | total | cold | " + " | ".join(keys) + " |",
                "|---:|---:|:---|:---|---:|---:|" + "---:|" * len(keys)]
        for b in sorted(bd, key=lambda b: (b["rays"], b["triangles"], b["solver"], b["stage"])):
            out.append(f"| {b['triangles']:,} | {b['rays']:.0e} | {name[b['solver']]} | {b['stage']} | "
                       f"{_f(b['best_s'])} | {_f(b['cold_s'])} | " + " | ".join(_f(b.get(k)) for k in keys) + " |")
    if res["memory"]:
        out += ["", f"Memory check (kill limit {res['meta']['mem_limit_gib']:.1f} GiB RSS; single cold run):", "",
                "| triangles | rays | solver | stage | status | time | peak RSS (VmHWM) [GiB] "
                "| peak RSS sampled | MemAvailable drop | Dr.Jit watermark | paths | pair-paths | note |",
                "|---:|---:|:---|:---|:---|---:|---:|---:|---:|---:|---:|---:|:---|"]
        for m in res["memory"]:
            out.append(f"| {m['triangles']:,} | {m['rays']:.0e} | {name[m['solver']]} | {m['stage']} | "
                       f"{m['status']} | {_f(m['time_s'], '{:.1f}')} | {_f(m['peak_gib'], '{:.2f}')} | "
                       f"{_f(m.get('peak_sampled_gib'), '{:.2f}')} | "
                       f"{_f(m.get('memavail_drop_gib'), '{:.2f}')} | "
                       f"{_f(m.get('drjit_watermark_gib'), '{:.2f}')} | "
                       f"{_f(m['paths'], '{:,}')} | {_f(m['pair_paths'], '{:.2e}')} | {m['note'] or ''} |")
    rr = res.get("round_ratios") or []
    if meta.get("rounds", 1) > 1 and rr:
        out += ["", f"Per-round ratios ({meta['rounds']} rounds; load average at the start of each "
                "round: " + ", ".join(f"{x[0]:.1f}" for x in meta.get("loadavg_rounds", [])) + "):", "",
                "| triangles | rays | stage | ours / Sionna per round | median |",
                "|---:|---:|:---|:---|---:|"]
        groups = {}
        for r in rr:
            groups.setdefault((r["rays"], r["triangles"], r["stage"]), []).append(r)
        for (rays, tri, st), g in sorted(groups.items()):
            vals = sorted(x["ratio"] for x in g)
            med = vals[len(vals) // 2] if len(vals) % 2 else 0.5 * (vals[len(vals) // 2 - 1] + vals[len(vals) // 2])
            out.append(f"| {tri:,} | {rays:.0e} | {st} | "
                       + ", ".join(f"{x['ours_s']:.3f}/{x['sionna_s']:.3f}={x['ratio']:.2f}" for x in g)
                       + f" | {med:.2f} |")
    out += ["", f"Total benchmark wall time: {meta['total_s']:.0f} s."]
    return "\n".join(out)


def _log(job, ev):
    msg = f"[{job['solver']:6s} tri={job['triangles']:.0e} rays={job['rays']:.0e}] {ev['stage']}: {ev['status']}"
    if ev.get("status") == "ok":
        msg += f" best {ev['best_s']:.3f}s peak {ev['peak_gib']:.2f}GiB paths {ev['info'].get('paths')}"
    print(msg, file=sys.stderr, flush=True)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="10k triangles, 1e3 rays only (< 1 min)")
    p.add_argument("--depth", type=int, default=3, help="max_depth of both solvers (default 3)")
    p.add_argument("--out", default=None, help="write the results as JSON here")
    p.add_argument("--mem-limit-gib", type=float, default=None,
                   help="kill a worker above this RSS (default min(20, 0.8 MemAvailable))")
    p.add_argument("--blas-threads", type=int, default=None,
                   help="OPENBLAS_NUM_THREADS for the workers (default: the environment's)")
    p.add_argument("--full-signal", action="store_true",
                   help="signal (ADC / CFR) stages at every mesh and ray count (about 15 min)")
    p.add_argument("--no-memory-check", action="store_true", help="skip the 1M-triangle / 1e6-ray runs")
    p.add_argument("--triangles", default=None,
                   help="custom grid: comma-separated triangle counts, e.g. 1e5,1e6 (paths stages only)")
    p.add_argument("--rays", default=None, help="custom grid: comma-separated ray counts, e.g. 1e4,1e5,1e6")
    p.add_argument("--signal", action="store_true", help="custom grid: the signal stages too")
    p.add_argument("--repeat", type=int, default=None, help="custom grid: timed runs per stage (default 2)")
    p.add_argument("--rounds", type=int, default=1,
                   help="run the plan this many times (solvers interleaved); best of the rounds, "
                        "and the per-round ratios")
    p.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        worker(json.loads(args.worker))
        return
    def nums(text):
        return None if not text else [int(float(x)) for x in text.split(",") if x.strip()]
    res = run(quick=args.quick, depth=args.depth, mem_limit_gib=args.mem_limit_gib,
              memory_check=not args.no_memory_check, log=_log,
              blas_threads=args.blas_threads, full_signal=args.full_signal,
              triangles=nums(args.triangles), rays=nums(args.rays), signal=args.signal,
              repeat=args.repeat, rounds=args.rounds)
    print(to_markdown(res))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
