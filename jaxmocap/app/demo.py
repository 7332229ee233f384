"""The end-to-end demo (`jaxmocap demo`, `make demo`): a walk, posed, exported and pictured,
then captured again from six simulated IMUs with SOP and SIP (von Marcard ch. 3).

Also exports a motion's meshes and pictures (`export_motion`, `jaxmocap export`).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from .._checks import output_folder
from ..body.io import resolve_body
from ..body.model import Body
from ..motion.io import find_cmu_dir

__all__ = ["DemoResult", "ExportResult", "export_motion", "run_demo"]


@dataclasses.dataclass(frozen=True)
class ExportResult:
    """What `export_motion` wrote."""

    meshes: list[Path]
    pictures: list[Path]
    num_frames: int


def export_motion(
    motion,
    body: Body,
    out_dir,
    fmt: str = "ply",
    every: int = 1,
    pictures: bool = True,
    glb: bool = False,
    progress: bool = False,
) -> ExportResult:
    """Pose `body` with `motion` and write meshes (and PNG pictures) into `out_dir`.

    Writes `out_dir/meshes/frame_XXXX.<fmt>` for every `every`-th frame (for fmt="glb",
    one `meshes/sequence.glb`), plus, with `glb=True`, that GLB in addition to PLY/OBJ;
    with `pictures`, `filmstrip.png` (skeleton filmstrip, trajectory, root height and
    speed) and `body.png` (the shaded mesh at mid-sequence, front/side/¾ views).
    """
    from ..body.posed import posed_vertices
    from ..viz.mesh import export_sequence
    from ..viz.plot import plot_body, plot_sequence

    out_dir = output_folder(out_dir, "out_dir")  # before posing, not when writing
    vertices, joints = posed_vertices(body, motion, progress=progress)
    meshes = export_sequence(vertices, body.faces, out_dir / "meshes", fmt=fmt, every=every, progress=progress)
    if glb and fmt != "glb":
        meshes += export_sequence(vertices, body.faces, out_dir / "meshes", fmt="glb", every=every)
    pngs = []
    if pictures:
        name = Path(motion.name).name if motion.name else "motion"
        pngs.append(
            plot_sequence(
                joints,
                body.parents,
                out_dir / "filmstrip.png",
                fps=motion.fps,
                joint_names=body.joint_names,
                title=f"{name}: {motion.num_frames} frames at {motion.fps:g} fps ({motion.duration:.2f} s)",
            )
        )
        mid = motion.num_frames // 2
        pngs.append(
            plot_body(
                vertices[mid],
                body.faces,
                out_dir / "body.png",
                joints=joints[mid],
                parents=body.parents,
                title=f"{name}, frame {mid} (t = {mid / motion.fps:.2f} s): {body.kind} body, "
                f"{body.num_vertices} vertices",
            )
        )
    return ExportResult(meshes=meshes, pictures=pngs, num_frames=motion.num_frames)


@dataclasses.dataclass(frozen=True)
class DemoResult:
    """What the demo did and wrote."""

    source: str
    num_frames: int
    fps: float
    meshes: list[Path]
    pictures: list[Path]
    seconds: float
    errors: dict = dataclasses.field(default_factory=dict)
    fit_seconds: dict = dataclasses.field(default_factory=dict)


def _demo_motion(body: Body, fps: float, seconds: float | None):
    from ..motion.io import load_motion

    cmu = find_cmu_dir()
    if cmu is not None and (cmu / "02_01.amc").is_file():
        motion = load_motion(cmu / "02_01.amc", fps=fps, body=body)
        source = f"CMU walk {cmu / '02_01.amc'}"
    else:
        try:
            from ..motion.library import walk
        except ImportError as e:
            raise FileNotFoundError(
                "No CMU clips found (set JAXMOCAP_CMU to the folder holding 02_01.amc) and the "
                f"procedural walk is unavailable ({e})."
            ) from e
        motion = walk(int(round((4.0 if seconds is None else seconds) * fps)) + 1, fps, body=body)
        source = "procedural walk (jaxmocap.motion.library.walk)"
    if seconds is None:  # the whole clip
        return motion, source
    frames = min(motion.num_frames, int(round(seconds * fps)) + 1)
    return motion[:frames], source


def run_demo(
    out_dir="out/demo",
    body: str | Body = "default-full",
    fps: float = 30.0,
    seconds: float | None = None,
    every: int = 5,
    progress: bool = False,
    fit: bool = True,
    seed: int = 0,
) -> DemoResult:
    """Load a walk (CMU 02_01 if present, else the procedural one), pose a body, export,
    then (with `fit`) simulate six IMUs with realistic errors and fit SOP and SIP.
    `seconds`: the length used (default: the whole clip; 2.83 s of CMU 02_01).

    Writes into `out_dir`: `meshes/frame_XXXX.ply` every `every` frames, one
    `meshes/sequence.glb` (a node per kept frame), `filmstrip.png` and `body.png`; with
    `fit` also `meshes_sop/` and `meshes_sip/` (the fitted poses, placed on the true root
    translation so that they overlay the truth), `sop_vs_sip.png` (MPJAE and MPJPE per
    frame) and `sop_vs_sip_joints.png` (MPJAE per joint).
    """
    start = time.perf_counter()
    output_folder(out_dir, create=False)  # a file given as --out fails now, not after the walk is posed
    body = resolve_body(body)
    motion, source = _demo_motion(body, fps, seconds)
    result = export_motion(motion, body, out_dir, fmt="ply", every=every, pictures=True, glb=True, progress=progress)
    meshes, pictures = list(result.meshes), list(result.pictures)
    errors, fit_seconds = {}, {}
    if fit:
        m2, p2, errors, fit_seconds = _fit_demo(motion, body, Path(out_dir), every, seed)
        meshes += m2
        pictures += p2
    return DemoResult(
        source=source,
        num_frames=motion.num_frames,
        fps=motion.fps,
        meshes=meshes,
        pictures=pictures,
        seconds=time.perf_counter() - start,
        errors=errors,
        fit_seconds=fit_seconds,
    )


def _fit_demo(motion, body: Body, out_dir: Path, every: int, seed: int):
    """Six IMUs (Xsens-like errors) from `motion`; SOP and SIP; plots and meshes."""
    import dataclasses as dc

    import jax
    import numpy as np

    from ..methods import inertial
    from .scenarios import inertial_setup
    from ..metrics import JOINT_SETS, pose_errors
    from ..viz.plot import plot_error_curves, plot_per_joint
    from ..motion.sequence import Motion
    from ..sensors import IMUErrorModel, ScenarioConfig, make_scenario
    from ..body.posed import posed_vertices
    from ..viz.mesh import export_sequence

    config = ScenarioConfig(
        fps=motion.fps, max_frames=motion.num_frames, imu_set="sip6", imu_errors=IMUErrorModel.xsens(), betas_std=0.0
    )
    scenario = make_scenario([motion], config, seed=seed, body=body)
    seq = scenario.sequence(0)
    truth, trans = seq["poses"][0], seq["trans"][0]
    setup = inertial_setup(scenario, 0, body)
    timings = {}
    t0 = time.perf_counter()
    sop, _ = inertial.sparse_orientation_poser(setup)
    jax.block_until_ready(sop)
    timings["SOP"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sip = inertial.sparse_inertial_poser(setup, init=sop)
    jax.block_until_ready(sip.poses)
    timings["SIP"] = time.perf_counter() - t0
    errors = {name: pose_errors(body, p, truth) for name, p in (("SOP", sop), ("SIP", sip.poses))}
    title = f"{Path(motion.name).name or 'motion'}: 6 IMUs, Xsens-like errors, {len(truth)} frames"
    pictures = [
        plot_error_curves({k: e["mpjae"] for k, e in errors.items()}, out_dir / "sop_vs_sip.png", motion.fps,
                          "MPJAE [°]", title),
        plot_error_curves({k: e["mpjpe"] for k, e in errors.items()}, out_dir / "sop_vs_sip_mpjpe.png",
                          motion.fps, "MPJPE (Procrustes) [mm]", title),
        plot_per_joint({k: e["mpjae"] for k, e in errors.items()}, JOINT_SETS["totalcapture_mpjae"],
                       out_dir / "sop_vs_sip_joints.png", "MPJAE [°]", title),
    ]  # fmt: skip
    meshes = []
    for name, poses in (("sop", sop), ("sip", sip.poses)):
        fitted = dc.replace(motion, poses=np.asarray(poses, np.float64), trans=np.asarray(trans, np.float64),
                            betas=np.zeros(0)) if isinstance(motion, Motion) else motion  # fmt: skip
        vertices, _ = posed_vertices(body, fitted)
        folder = out_dir / f"meshes_{name}"
        meshes += export_sequence(vertices, body.faces, folder, fmt="ply", every=every)
        meshes += export_sequence(vertices, body.faces, folder, fmt="glb", every=every)
    summary = {k: {m: float(np.mean(v)) for m, v in e.items()} for k, e in errors.items()}
    return meshes, pictures, summary, timings
