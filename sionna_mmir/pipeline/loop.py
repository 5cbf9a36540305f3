"""``run_loop``: fit, diagnose, adopt, refit jointly, report -- closing the loop.

Stages (each checkpointed; ``resume`` continues after the last finished one):

1. **load** -- the capture (any format the package reads; a ColoRadar run's
   radar pose from its own ``calib/transforms``), the meshes (or, for a
   corner-reflector capture without a mesh, the trihedral-and-floor scene
   at the detected corner);
2. **fit** -- per-vertex materials and beam patterns to the range-azimuth
   map (:class:`~sionna_mmir.fit.MMIRModel`), its target phase-calibrated
   per channel against the initial scene where the array's phases are
   scrambled (:mod:`~sionna_mmir.fit.target_calibration`);
3. **base** -- the fitted scene rendered and split per object, refined in
   the complex ADC domain (per-object gains, radar pose against the mesh
   frame): the *first* model, right in range and phase;
4. **diagnose** -- candidates (scene-side and sensor effects) ranked by
   how well they predict held-out channels; the best is adopted and
   everything refitted jointly, until nothing helps
   (:class:`~sionna_mmir.residual.diagnosis.DiagnosisRun`);
5. **report** -- ``report.json``, ``report.md``, pictures, the final
   model's render and the fitted scene.
"""
from __future__ import annotations

import dataclasses
import os
import pickle
import shutil
import time

import numpy as np

from ..errors import ConfigError, InputValueError
from ..residual.ranking import BIC, check_penalty
from ..residual.workers import AUTO, FitPool, check_workers
from .radar_model import RadarModel, loop_solver_options

#: format tag of the loop's checkpoint file
STATE_FORMAT = ("sionna_mmir.loop_state", 2)


#: a first fit is flagged as "barely overlapping" when it leaves this much of the
#: capture's energy [dB] *and* its range-azimuth map correlates this little
OVERLAP_RESIDUAL_DB, OVERLAP_RA_CORRELATION = -1.0, 0.2


def overlap_warning(first: dict, source: str):
    """The warning for a first fit that barely overlaps the capture, or None.

    ``first``: the first fit's metrics (``residual_energy_db``,
    ``ra_correlation``).  Both must say so: the ADC residual alone also stays
    near 0 dB when a strong sensor effect (per-channel phases, a delay
    offset) is still unmodelled, while the range-azimuth *magnitude* map then
    still matches (RA corr 0.35-0.7 on such runs against ~0 for a mesh in the
    wrong frame).
    """
    e = float(first.get("residual_energy_db", 0.0))
    ra = float(first.get("ra_correlation", 0.0))
    if e <= OVERLAP_RESIDUAL_DB or ra >= OVERLAP_RA_CORRELATION:
        return None
    return (f"{source}: the scene explains only {100 * (1 - 10 ** (e / 10)):.0f} % of the "
            f"capture's energy and its range-azimuth map correlates {ra:.2f} with the capture's: "
            "the meshes and the capture barely overlap (is the mesh in the radar's scene frame, "
            "+x boresight, +y left, +z up? give --position / --orientation)")


@dataclasses.dataclass
class LoopRequest:
    """What one ``loop`` run does.

    Parameters
    ----------
    capture : str
        Capture path (any format :func:`~sionna_mmir.captures.load_capture` reads).
    out : str
        Report folder.
    meshes : dict
        Object name -> mesh path (in the radar's scene frame); empty with
        ``scene="corner"``.
    scene : {"meshes", "corner"}
        Where the scene comes from.
    materials : dict
        Object name -> ITU-R P.2040 material (default concrete; metal for
        the corner scene's reflector).
    position, orientation : tuple or None
        Radar pose [m], (yaw, pitch, roll) [rad]; ``None``: the run's own
        transforms (ColoRadar), else the origin.
    fit_iterations : int
        Adam steps of the range-azimuth fit (0: skip it).
    waveform : dict
        Waveform values the capture file lacks (``load_capture(waveform=...)``).
    sensor_profile : str, optional
        A unit's profile file, applied frozen to the forward model (the RA fit
        and the sensor chain; :mod:`sionna_mmir.effects.profile`).
    folds, penalty
        Cross-validation folds; nats per candidate parameter (``"bic"``:
        ``ln(n) / 2``, :func:`~sionna_mmir.residual.ranking.penalty_per_param`).
    workers : int or "auto"
        Processes for the independent fits of a diagnosis round
        (:class:`~sionna_mmir.residual.workers.FitPool`; ``"auto"``: one per core).
    """

    capture: str
    out: str
    meshes: dict = dataclasses.field(default_factory=dict)
    scene: str = "meshes"
    materials: dict = dataclasses.field(default_factory=dict)
    frame: int | None = None
    calib_dir: str | None = None
    sensor: str = "cascade"
    position: tuple | None = None
    orientation: tuple | None = None
    fit_iterations: int = 10
    lr: float = 0.05
    seed: int = 0
    solver: object = dataclasses.field(default_factory=loop_solver_options)
    effects: object = None
    folds: int = 3
    penalty: object = BIC
    max_objects: int = 8
    resume: bool = False
    overwrite: bool = False
    progress: bool = True
    waveform: dict = dataclasses.field(default_factory=dict)
    sensor_profile: str | None = None
    workers: object = AUTO


def check_request(req: LoopRequest) -> None:
    """Refuse impossible settings before any work."""
    if os.path.exists(req.out) and not (req.overwrite or req.resume):
        raise FileExistsError(f"{req.out}: report folder exists (use --overwrite or --resume)")
    if req.scene not in ("meshes", "corner"):
        raise ConfigError(f"scene must be 'meshes' or 'corner', got {req.scene!r}")
    if req.scene == "meshes" and not req.meshes:
        raise ConfigError("no meshes given (pass mesh files, or --scene corner for a corner "
                          "reflector capture)")
    if req.fit_iterations < 0:
        raise ConfigError(f"--fit-iterations must be >= 0, got {req.fit_iterations}")
    if req.folds < 2:
        raise ConfigError(f"--folds must be >= 2, got {req.folds}")
    check_penalty(req.penalty)
    check_workers(req.workers)
    if req.effects is not None:
        default_candidates(req.effects)               # unknown or empty lists, up front


def load_capture_posed(req: LoopRequest):
    """The capture with its radar at the requested pose (else the run's own)."""
    from ..captures.loader import load_capture

    cap = load_capture(req.capture, frame=req.frame, calib_dir=req.calib_dir, sensor=req.sensor,
                       waveform=req.waveform)
    if not np.isfinite(cap.frames.real).all() or not np.isfinite(cap.frames.imag).all():
        raise InputValueError(f"{req.capture}: capture holds NaN or Inf samples")
    position, orientation = req.position, req.orientation
    if position is None and orientation is None:
        position, orientation = _run_pose(req) or (cap.radar.position, cap.radar.orientation)
    radar = dataclasses.replace(
        cap.radar, position=tuple(np.zeros(3) if position is None else position),
        orientation=tuple(np.zeros(3) if orientation is None else orientation))
    return dataclasses.replace(cap, radar=radar)


def _run_pose(req):
    """The radar pose a ColoRadar run stores in ``calib/transforms``, or ``None``."""
    from ..captures.coloradar import find_calib_dir
    from ..captures.coloradar_calib import coloradar_pose

    where = req.calib_dir
    if where is None and os.path.isdir(req.capture):
        where = find_calib_dir(req.capture, req.sensor)
    return None if where is None else coloradar_pose(where, req.sensor)


def build_scene(req: LoopRequest, cap):
    """The scene of the request: its meshes, or the corner scene at the
    capture's strongest return."""
    from ..scene import load_scene

    if req.scene == "corner":
        from ..compare.corner_scene import CORNER_MATERIALS, corner_scene_meshes
        from ..compare.demo import detect_corner_and_leakage

        r, az, _, centre = detect_corner_and_leakage(cap.frame(0))
        meshes = corner_scene_meshes(r, az, centre)
        return load_scene(meshes, materials={**CORNER_MATERIALS, **req.materials},
                          radar=cap.radar), {"corner_range_m": r,
                                             "corner_azimuth_deg": float(np.degrees(az))}
    unknown = sorted(set(req.materials) - set(req.meshes))
    if unknown:
        raise ConfigError(f"--material given for unknown objects {unknown}")
    return load_scene(req.meshes, materials=req.materials, radar=cap.radar), {}


def default_candidates(names=None) -> list:
    """Candidate effects of a loop: the library and the scene-side refinements
    (``names``: a list or comma-separated string; ``None``: all)."""
    from ..effects.library import LIBRARY
    from ..effects.library.scene_mismatch import ObjectDelay, ObjectPattern, ObjectShift

    extra = {"object_delay": ObjectDelay, "object_shift": ObjectShift,
             "object_pattern": ObjectPattern}
    known = {**LIBRARY, **extra}
    if names is None:
        return [cls() for cls in known.values()]
    if isinstance(names, str):
        names = names.split(",")
    names = [n.strip() for n in names if n.strip()]
    bad = sorted(set(names) - set(known))
    if bad or not names:
        raise ConfigError(f"--effects: unknown effect(s) {bad}; choose from {sorted(known)}"
                          if bad else "--effects: empty list of candidate effects")
    return [known[n]() for n in names]


class Loop:
    """One resumable ``loop`` run (see the module docstring)."""

    def __init__(self, req: LoopRequest):
        check_request(req)
        self.req = req
        self.tmp = req.out.rstrip("/") + ".partial"
        self.state_path = os.path.join(self.tmp, "loop_state.pkl")
        self.timings, self.info, self.run = {}, {}, None
        self.model = None

    # ------------------------------------------------------------ stages
    def prepare(self):
        """Load the capture and the scene, and restore a checkpoint to resume."""
        t0 = time.perf_counter()
        cap = load_capture_posed(self.req)
        scene, self.info = build_scene(self.req, cap)
        profile = None
        if self.req.sensor_profile is not None:
            from ..effects.profile import load_for

            profile = load_for(self.req.sensor_profile, cap.radar)
        self.model = RadarModel(scene, cap, solver=self.req.solver,
                                max_objects=self.req.max_objects, profile=profile)
        self.timings["load_s"] = time.perf_counter() - t0
        if os.path.exists(self.tmp) and not self.req.resume:
            shutil.rmtree(self.tmp)
        os.makedirs(self.tmp, exist_ok=True)
        saved = self._load_state() if self.req.resume else None
        if saved is not None:
            try:
                self.model.restore(saved["model"])
            except InputValueError as err:
                raise InputValueError(f"{self.state_path}: {err}") from None
            self.run, self.timings = saved["run"], saved["timings"]
            if self.run is not None:
                self.run.model = self.model.chain
                self.run.progress = self._progress
                self.run.fits = FitPool(self.req.workers)
        return self

    def fit_scene(self):
        """Stage 2: the range-azimuth fit of materials and beam patterns."""
        if self.model.latents is not None or self.req.fit_iterations == 0:
            return
        from ..fit import fit

        t0 = time.perf_counter()
        model = self.model.mmir
        if self.model.profile is not None:
            from ..fit.profiled import ProfiledModel

            model = ProfiledModel(model, self.model.profile, self.model.capture.frames[0])
        res = fit(model, self._target(model),
                  iterations=self.req.fit_iterations, lr=self.req.lr, seed=self.req.seed,
                  progress=self.req.progress,
                  checkpoint=os.path.join(self.tmp, "fit_mmir.h5"))
        self.model.latents = res.latents
        self.timings["fit_s"] = time.perf_counter() - t0
        self._save_state()

    def _target(self, model):
        """The RA fit target: the capture's map, phase-calibrated per channel
        against the initial scene where that clearly helps (not under a
        sensor profile, which carries the unit's calibration)."""
        from ..compare.harness import target_ra
        from ..fit.target_calibration import calibrate_target
        from ..paths.render import to_numpy

        frames = self.model.capture.frames
        if self.model.profile is not None:
            return target_ra(frames, self.model.radar)
        adc, _ = model.render(model.latents(), seed=self.req.seed)
        target, cal = calibrate_target(frames, to_numpy(adc), self.model.radar)
        self.info["target_calibration"] = cal.summary()
        return target

    def base(self):
        """Stage 3: the per-object basis and its complex-domain refinement."""
        if self.run is not None:
            return
        from ..residual.diagnosis import DiagnosisRun

        t0 = time.perf_counter()
        self.model.render_basis(seed=self.req.seed)
        self.model.attach()
        self.scene_mismatch = self.model.refine()
        self.run = DiagnosisRun(self.model.chain, default_candidates(self.req.effects),
                                folds=self.req.folds, penalty=self.req.penalty,
                                seed=self.req.seed, progress=self._progress,
                                workers=self.req.workers)
        self.timings["base_s"] = time.perf_counter() - t0
        self._check_overlap()
        self._save_state()

    def diagnose(self):
        """Stage 4: rounds until nothing helps (checkpoint after each)."""
        from tqdm import tqdm

        t0 = time.perf_counter()
        self._bar = tqdm(desc="diagnosis", unit="fit", disable=not self.req.progress,
                         leave=False)
        while not self.run.done:
            self.run.step()
            self._save_state()
        self._bar.close()
        self.timings["diagnose_s"] = self.timings.get("diagnose_s", 0.0) + \
            time.perf_counter() - t0

    def report(self) -> dict:
        """Stage 5: write the report folder and return ``report.json``'s content."""
        from .report import write_loop_report

        doc = write_loop_report(self, self.tmp)
        for name in ("loop_state.pkl", "basis.pkl"):
            if os.path.exists(os.path.join(self.tmp, name)):
                os.remove(os.path.join(self.tmp, name))
        if os.path.exists(self.req.out):
            shutil.rmtree(self.req.out)
        os.replace(self.tmp, self.req.out)
        return doc

    # ----------------------------------------------------------- helpers
    def _progress(self, event, name):
        bar = getattr(self, "_bar", None)
        if bar is None:
            return
        if event == "scored":
            bar.set_postfix_str(f"scored {name}")
            bar.update(1)
        else:
            bar.write(f"{event} {name}")

    def _check_overlap(self):
        """Warn when the scene explains little of the capture (wrong frame?)."""
        msg = overlap_warning(self.run.first, self.req.capture)
        if msg is not None:
            import warnings

            self.info["overlap_warning"] = msg
            warnings.warn(msg, stacklevel=2)

    def _save_state(self):
        from ..utils.atomic import atomic_path

        model_state = self.model.state()
        basis_path = os.path.join(self.tmp, "basis.pkl")
        if model_state["basis"] is not None and not os.path.exists(basis_path):
            with atomic_path(basis_path) as tmp:
                with open(tmp, "wb") as f:
                    pickle.dump(model_state["basis"], f)
        model_state["basis"] = None
        state = {"format": STATE_FORMAT, "model": model_state, "run": self.run,
                 "timings": self.timings, "info": self.info,
                 "scene_mismatch": getattr(self, "scene_mismatch", None)}
        run, saved = self.run, None
        if run is not None:
            saved, run.model, run.progress = (run.model, run.progress), None, None
        try:
            with atomic_path(self.state_path) as tmp:
                with open(tmp, "wb") as f:
                    pickle.dump(state, f)
        finally:
            if saved is not None:
                run.model, run.progress = saved

    def _load_state(self):
        if not os.path.exists(self.state_path):
            return None
        with open(self.state_path, "rb") as f:
            state = pickle.load(f)
        if state.get("format") != STATE_FORMAT:
            raise InputValueError(f"{self.state_path}: not a loop checkpoint of this version")
        basis_path = os.path.join(self.tmp, "basis.pkl")
        if os.path.exists(basis_path):
            with open(basis_path, "rb") as f:
                state["model"]["basis"] = pickle.load(f)
        self.info = state["info"]
        self.scene_mismatch = state["scene_mismatch"]
        return state


def run_loop(req: LoopRequest) -> dict:
    """Run (or resume) a loop and return its report (``report.json``)."""
    loop = Loop(req)
    try:
        loop.prepare()
        loop.fit_scene()
        loop.base()
        loop.diagnose()
        return loop.report()
    except Exception:
        if not req.resume and os.path.exists(loop.tmp):
            shutil.rmtree(loop.tmp, ignore_errors=True)
        raise


__all__ = ["LoopRequest", "Loop", "run_loop", "default_candidates", "check_request"]
