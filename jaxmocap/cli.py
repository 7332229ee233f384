"""The `jaxmocap` command: inspect, convert, export, demo.

Each subcommand is one `configure(parser)` function that declares its arguments and one
`run(args) -> int` function that does the work; `COMMANDS` registers them. To add a
subcommand (fit, check, sweep, ...), write those two functions and append a `Command`.

User mistakes (missing files, unreadable or unknown formats, bad values) print one line
`jaxmocap <command>: error: <message>` on stderr and exit with status 2; `--debug` shows
the traceback instead.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

__all__ = ["COMMANDS", "Command", "main", "build_parser"]


@dataclasses.dataclass(frozen=True)
class Command:
    """A subcommand: its name, one-line help, argument declarations and action."""

    name: str
    help: str
    configure: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int | None]


def _add_body_option(parser: argparse.ArgumentParser, default: str = "default-low") -> None:
    parser.add_argument(
        "--body",
        default=default,
        metavar="BODY",
        help="body model: default-low, default-full, mannequin, or a model file "
        f"(.pkl/.npz; SMPL, SMPL-H, SMPL-X) (default: {default})",
    )


def _load_motion(path, fps=None, body=None, **options):
    from .motion.io import load_motion

    return load_motion(path, fps=fps, body=body, **options)


def _positive(kind):
    def parse(text: str):
        value = kind(text)
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be positive, got {text}")
        return value

    return parse


# --- inspect ------------------------------------------------------------------------


def _configure_inspect(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="a motion file (.npz AMASS/jaxmocap, .amc, .bvh) or a body model (.pkl/.npz)")
    p.add_argument("--map", help="joint map for a .bvh/.amc: a built-in rig name or a TOML/JSON file (default: detect)")


def _is_body_file(path: Path) -> bool:
    if path.suffix.lower() == ".pkl":
        return True
    if path.suffix.lower() != ".npz" or not path.is_file():
        return False
    import numpy as np

    try:
        with np.load(path, allow_pickle=False) as f:
            return "v_template" in f.files
    except Exception:  # unreadable: let the motion loader name the problem
        return False


def _run_inspect(args) -> int:
    import numpy as np

    path = Path(args.file)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file.")
    if _is_body_file(path):
        if args.map:
            raise ValueError("--map applies to .bvh/.amc motion files, not to a body model.")
        from .body.io import load_body

        body = load_body(path)
        v = np.asarray(body.v_template)
        print(f"body model   {path}")
        print(f"kind         {body.kind} ({body.gender})")
        print(f"vertices     {body.num_vertices}")
        print(f"faces        {len(body.faces)}")
        print(f"joints       {body.num_joints}")
        print(f"betas        {body.num_betas} shape components")
        print(f"rest height  {np.ptp(v[:, 1]):.3f} m (template, y up)")
        return 0
    rig = _describe_rig(path, args.map)
    motion = _load_motion(path, **({"mapping": args.map} if args.map else {}))
    trans = motion.trans
    step = np.linalg.norm(np.diff(trans, axis=0), axis=1)
    ground = np.linalg.norm(np.diff(trans[:, [0, 2]], axis=0), axis=1)
    betas = np.array2string(motion.betas, precision=3, max_line_width=88) if motion.betas.size else "none (mean shape)"
    print(f"motion       {path}")
    print(f"frames       {motion.num_frames}")
    print(f"fps          {motion.fps:g}")
    print(f"duration     {motion.duration:.3f} s")
    print(f"joints       {motion.poses.shape[1]} (SMPL tree)")
    print(f"root path    {step.sum():.3f} m ({ground.sum():.3f} m on the ground plane)")
    print(f"root height  {trans[:, 1].min():.3f} .. {trans[:, 1].max():.3f} m (y up)")
    print(f"gender       {motion.gender}")
    print(f"betas        {betas}")
    for line in rig:
        print(line)
    return 0


def _describe_rig(path: Path, mapping) -> list[str]:
    """Lines naming the skeleton's rig and how it is retargeted (BVH and ASF/AMC only)."""
    from .body.io import default_body
    from .motion.retarget import OPTIONAL_JOINTS, RIGS, resolve_mapping, rest_kind, smpl_rest, strip_namespace

    if path.suffix.lower() == ".bvh":
        from .motion.bvh import load_bvh

        src = load_bvh(path)
    elif path.suffix.lower() == ".amc":
        from .motion.asf_amc import load_asf_amc

        src = load_asf_amc(path)
    else:
        return []
    src = strip_namespace(src)
    name, table = resolve_mapping(mapping, src)
    rest = rest_kind(src, smpl_rest(default_body())[0], table)
    label = RIGS[name][0] if name in RIGS else name
    used = [k for k, v in table.items() if all(j in src.names for j in ((v,) if isinstance(v, str) else v))]
    left = [n for n in OPTIONAL_JOINTS if n not in used]
    return [
        f"rig          {label} ({len(src.names)} source joints, {len(used)}/24 SMPL joints mapped"
        + (f"; at rest: {', '.join(left)})" if left else ")"),
        f"rest         {rest}: "
        + (
            "the all-zero pose stands like SMPL's"
            if rest == "zero"
            else "bones carry their own frames; rest taken from the clip"
        ),
    ]


# --- convert ------------------------------------------------------------------------


def _configure_convert(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="any readable motion file (.npz, .amc, .bvh)")
    p.add_argument("output", help="AMASS-style .npz to write (z up, as AMASS)")
    p.add_argument("--fps", type=_positive(float), help="resample to this frame rate")
    _add_body_option(p)


def _run_convert(args) -> int:
    from .motion.amass import save_amass
    from .body.io import resolve_body

    out = Path(args.output)
    if out.suffix.lower() != ".npz":
        raise ValueError(f"{out}: the output must be an .npz file (AMASS layout).")
    body = resolve_body(args.body)
    motion = _load_motion(args.input, fps=args.fps, body=body)
    out.parent.mkdir(parents=True, exist_ok=True)
    written = save_amass(motion, out, body=body)
    print(f"wrote {written}: {motion.num_frames} frames at {motion.fps:g} fps ({motion.duration:.2f} s)")
    return 0


# --- export -------------------------------------------------------------------------


def _configure_export(p: argparse.ArgumentParser) -> None:
    p.add_argument("motion", help="motion file (.npz, .amc, .bvh)")
    p.add_argument("outdir", help="folder for meshes/ and pictures")
    _add_body_option(p)
    p.add_argument("--format", default="ply", choices=("ply", "glb", "obj"), help="mesh format (default: ply)")
    p.add_argument("--every", type=_positive(int), default=1, metavar="N", help="keep every N-th frame")
    p.add_argument("--fps", type=_positive(float), help="resample the motion first")
    p.add_argument("--png", action="store_true", help="also write filmstrip.png and body.png")


def _run_export(args) -> int:
    from ._checks import output_folder
    from .app.demo import export_motion
    from .body.io import resolve_body

    output_folder(args.outdir, "OUTDIR", create=False)  # before the motion is loaded and posed
    body = resolve_body(args.body)
    motion = _load_motion(args.motion, fps=args.fps, body=body)
    result = export_motion(
        motion,
        body,
        args.outdir,
        fmt=args.format,
        every=args.every,
        pictures=args.png,
        progress=sys.stderr.isatty(),
    )
    where = result.meshes[0].parent if result.meshes else Path(args.outdir)
    print(
        f"wrote {len(result.meshes)} {args.format.upper()} file(s) to {where} "
        f"({motion.num_frames} frames, every {args.every})"
    )
    for png in result.pictures:
        print(f"wrote {png}")
    return 0


# --- demo ---------------------------------------------------------------------------


def _configure_demo(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    _add_body_option(p, default="default-full")
    p.add_argument(
        "--seconds",
        type=_positive(float),
        default=None,
        help="length of the clip (default: all of it, 2.83 s of CMU 02_01)",
    )
    p.add_argument("--every", type=_positive(int), default=5, metavar="N", help="PLY every N frames (default: 5)")
    p.add_argument("--no-fit", action="store_true", help="skip the IMU simulation and the SOP/SIP fits")


def _mesh_lines(meshes) -> list[str]:
    """One line per folder of PLY files: the demo writes meshes/, meshes_sop/ and
    meshes_sip/, and one count for all three read as 54 files in meshes/."""
    folders: dict[Path, list[Path]] = {}
    for p in meshes:
        if p.suffix == ".ply":
            folders.setdefault(p.parent, []).append(p)
    return [
        f"meshes   {len(set(ps))} PLY in {folder} ({ps[0].name} .. {ps[-1].name})" for folder, ps in folders.items()
    ]


def _run_demo(args) -> int:
    from .app.demo import run_demo

    result = run_demo(
        args.out,
        body=args.body,
        seconds=args.seconds,
        every=args.every,
        progress=sys.stderr.isatty(),
        fit=not args.no_fit,
    )
    glbs = [p for p in result.meshes if p.suffix == ".glb"]
    print(f"motion   {result.source}: {result.num_frames} frames at {result.fps:g} fps")
    for line in _mesh_lines(result.meshes):
        print(line)
    for p in glbs:
        print(f"scene    {p} (one node per kept frame, y up)")
    for p in result.pictures:
        print(f"picture  {p}")
    if result.errors:
        print("fit      6 simulated IMUs (Xsens-like errors), calibrated on the true first pose")
        for name, e in result.errors.items():
            print(
                f"  {name:4s} MPJPE {e['mpjpe']:6.1f} mm (Procrustes)  MPJAE {e['mpjae']:5.1f}°  "
                f"({result.fit_seconds[name]:.1f} s incl. compilation)"
            )
        sop, sip = result.errors.get("SOP"), result.errors.get("SIP")
        if sop and sip:
            gain = lambda k: 100.0 * (sip[k] - sop[k]) / sop[k]  # noqa: E731
            print(
                f"  SIP vs SOP: MPJPE {gain('mpjpe'):+.0f} %, MPJAE {gain('mpjae'):+.0f} % "
                "(thesis, TotalCapture: -31 %, -26 %)"
            )
    print(f"done in {result.seconds:.1f} s")
    return 0


# --- check --------------------------------------------------------------------------


def _configure_check(p: argparse.ArgumentParser) -> None:
    p.add_argument("motion", help="motion file (.npz, .amc, .bvh)")
    _add_body_option(p)
    p.add_argument("--fps", type=_positive(float), help="resample the motion first")
    p.add_argument("--ground", default="0", metavar="HEIGHT", help="floor height y in metres, or 'auto' (default: 0)")
    p.add_argument("--out", metavar="DIR", help="write <name>_check.png (and the heat map .ply) here")


def _run_check(args) -> int:
    from .app.physics import run_check

    return run_check(args.motion, body=args.body, fps=args.fps, ground=args.ground, out=args.out)


# --- multiview ----------------------------------------------------------------------


def _frame_slice(text: str) -> slice:
    start, sep, stop = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return slice(int(start) if start else None, int(stop) if stop else None)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START:STOP frame numbers (e.g. 0:300), got {text!r}") from None


def _configure_multiview(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "source",
        nargs="?",
        metavar="PROJECT|demo",
        help="a Pose2Sim-style project folder (Config.toml, calibration/, pose/camNN_json/), read with no "
        "other flags; or 'demo': write a small synthetic recording in that layout into --out and fit it "
        "(a folder named demo: ./demo)",
    )
    p.add_argument(
        "--keypoints",
        metavar="DIR",
        help="folder with one OpenPose JSON folder per camera (default: the project's pose/)",
    )
    p.add_argument(
        "--calib",
        metavar="FILE",
        help="calibration: Pose2Sim .toml, Qualisys .qca.txt, EasyMocap "
        "intri/extri.yml (folder), .npz (default: the project's calibration/)",
    )
    p.add_argument(
        "--out",
        metavar="DIR",
        help="output folder (default: PROJECT/multiview for a project, multiview-demo for the demo)",
    )
    p.add_argument(
        "--videos",
        metavar="DIR",
        help="one video per camera (cam01.mp4, ...): detect the person with MediaPipe Pose (an "
        "environment of its own: --detector-python) instead of reading --keypoints",
    )
    p.add_argument(
        "--detector-python",
        metavar="PYTHON",
        default=None,
        help="the Python with mediapipe 0.10.21 for --videos (default: $JAXMOCAP_VIDEO_PYTHON, else this one)",
    )
    p.add_argument(
        "--layout",
        default=None,
        choices=("body25", "body25b", "coco18", "halpe26", "mediapipe33"),
        help="the model the keypoints come from (OpenPose's; halpe26: RTMPose's, Pose2Sim >= 0.9's; "
        "mediapipe33: MediaPipe Pose's, what --videos writes) (default: Config.toml's pose_model, else "
        "detected from the skeleton); checked against the skeleton either way",
    )
    _add_body_option(p)
    p.add_argument(
        "--views",
        type=lambda s: [v for v in s.split(",") if v],
        metavar="A,B",
        help="camera folders to use (default: all)",
    )
    p.add_argument("--frames", type=_frame_slice, metavar="START:STOP", help="frame numbers to fit (default: all)")
    p.add_argument(
        "--fps",
        type=_positive(float),
        default=None,
        help="frame rate of the recording (default: Config.toml's frame_rate, else 30)",
    )
    p.add_argument("--no-temporal", action="store_true", help="stop after stage 1 (no DCT temporal prior)")
    p.add_argument(
        "--keep-swaps",
        action="store_true",
        help="do not flip back views whose detector swapped the legs (MuVS as written)",
    )
    p.add_argument("--masks", metavar="DIR", help="person masks: one folder of PNGs per camera (adds silhouettes)")
    p.add_argument(
        "--floor",
        type=float,
        default=None,
        metavar="HEIGHT",
        help="the floor's height in metres along the calibration world's up axis (0 for Qualisys and Pose2Sim "
        "calibrations): with one camera the fit stands the feet on it, which measures the depth that one view "
        "does not (default: no floor; not used with several cameras)",
    )
    p.add_argument(
        "--weights",
        default="validated",
        choices=("validated", "thesis"),
        help="MuVS's weights (methods.multiview.PRESETS): validated, chosen on the development subjects "
        "(pose prior λ_θ 1, shape prior λ_β 50; experiments/results/muvs_tuning.json), or thesis, the "
        "values this implementation started with (λ_θ 20, λ_β 50) (default: validated)",
    )


def _say(line: str) -> None:
    print(line, file=sys.stderr if line.startswith("warning") else sys.stdout, flush=True)


def _run_multiview(args) -> int:
    from .app.multiview import fit_recording

    if args.source == "demo":
        from .app.multiview_demo import run_demo

        out = Path(args.out or "multiview-demo")
        r = run_demo(out, body=args.body, temporal=not args.no_temporal, log=_say, progress=sys.stderr.isatty(),
                     weights=args.weights)  # fmt: skip
        out = out / "fit"
    else:
        keypoints, calib, out = args.keypoints, args.calib, args.out
        if args.videos is not None and keypoints is not None:
            raise ValueError("--videos and --keypoints both given: the keypoints come from one or the other.")
        if args.source is not None:
            from .formats import read_project

            project = read_project(args.source, need_keypoints=keypoints is None and args.videos is None,
                                   need_calibration=calib is None)  # fmt: skip
            keypoints, calib = keypoints or project.keypoints, calib or project.calibration
            out = out or project.root / "multiview"
        source = ("--videos DIR", args.videos) if args.videos is not None else ("--keypoints DIR", keypoints)
        missing = [flag for flag, value in (source, ("--calib FILE", calib), ("--out DIR", out)) if value is None]
        if missing:
            raise ValueError(f"missing {', '.join(missing)}: give a project folder (jaxmocap multiview PROJECT), "
                             "or --keypoints DIR (or --videos DIR) --calib FILE --out DIR.")  # fmt: skip
        out = Path(out)
        options = dict(body=args.body, frames=args.frames, temporal=not args.no_temporal,
                       resolve_swaps=not args.keep_swaps, masks_dir=args.masks, fps=args.fps,
                       weights=args.weights, floor=args.floor, progress=sys.stderr.isatty(), log=_say)  # fmt: skip
        if args.videos is not None:
            from .app.multiview_video import fit_videos

            if args.layout not in (None, "mediapipe33"):
                raise ValueError(f"--layout {args.layout} with --videos: the video detector gives mediapipe33.")
            views = None if args.views is None else [v.removesuffix("_json") for v in args.views]
            r = fit_videos(args.videos, calib, out, detector_python=args.detector_python, views=views, **options)
        else:
            r = fit_recording(keypoints, calib, out, layout=args.layout, views=args.views, **options)
    final = r["reprojection"]["final"]
    num = lambda x, spec: "-" if x is None else format(x, spec)  # noqa: E731 (None: nothing to measure)
    per_view = ", ".join(f"{v} {num(s['median_px'], '.1f')}" for v, s in final["per_view"].items())
    print(
        f"fitted   {r['frames']['count']} frames x {len(r['views'])} views ({r['layout']}) in "
        f"{r['timings_s']['total']:.1f} s"
    )
    print(
        f"reproj   median {num(final['overall']['median_px'], '.1f')} px, "
        f"mean {num(final['overall']['mean_px'], '.1f')} px "
        f"(per view median: {per_view})"
    )
    jitter = r["jitter_mm_s2"]
    print(f"jitter   stage 1 {num(jitter['stage1'], '.0f')} mm/s^2, final {num(jitter['final'], '.0f')} mm/s^2")
    print(
        f"wrote    {out / r['outputs']['smpl']}, {len(r['outputs']['overlays'])} overlays in {out / 'overlays'}, "
        f"meshes in {out / 'meshes'}, {out / 'report.md'}"
    )
    if "demo" in r:
        print(
            f"demo     MPJPE {r['demo']['mpjpe_mm']:.0f} mm against the simulated walk; {r['demo']['seconds']:.0f} s "
            f"in all. Your own: jaxmocap multiview PROJECT (a folder laid out as {out.parent / 'recording'})"
        )
    return 0


# --- interaction --------------------------------------------------------------------


def _configure_interaction(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="interaction_action", metavar="ACTION", required=True)
    d = sub.add_parser(
        "demo",
        help="simulate a person carrying an object (RGB-D views), fit it with InterCap, score it",
        description="Simulate a person walking with an object (library walk, bundled meshes, no "
        "downloads) seen by static RGB-D cameras, fit it with InterCap (Huang ch. 5: object "
        "tracking, human fit, contact detection, joint fit) and write result.npz, metrics.json, "
        "a contact heat map (PLY, PNG), a penetration histogram and the middle frame as GLB.",
    )
    d.add_argument("--out", required=True, metavar="DIR", help="output folder")
    d.add_argument("--frames", type=_positive(int), default=30, metavar="N", help="frames to simulate (default: 30)")
    d.add_argument("--object", default="box", choices=("box", "bottle", "chair"), help="the object (default: box)")
    d.add_argument("--views", type=_positive(int), default=3, metavar="V", help="RGB-D cameras (default: 3)")
    d.add_argument(
        "--size", type=_image_size, default=(160, 120), metavar="WxH", help="image size in pixels (default: 160x120)"
    )
    d.add_argument(
        "--depth-points",
        type=_positive(int),
        default=512,
        metavar="M",
        help="depth points per view and frame (default: 512)",
    )
    d.add_argument("--seed", type=int, default=0, help="seed of the simulation (default: 0)")
    _add_body_option(d)


def _image_size(text: str) -> tuple[int, int]:
    w, sep, h = text.lower().partition("x")
    try:
        if not sep or int(w) <= 0 or int(h) <= 0:
            raise ValueError
        return int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels (e.g. 160x120), got {text!r}") from None


def _run_interaction(args) -> int:
    from .app.interaction import run_interaction_demo

    r = run_interaction_demo(args.out, frames=args.frames, object=args.object, views=args.views, width=args.size[0],
                             height=args.size[1], depth_points=args.depth_points, seed=args.seed, body=args.body,
                             progress=sys.stderr.isatty())  # fmt: skip
    num = lambda x, spec: "-" if x is None else format(x, spec)  # noqa: E731 (None: nothing to measure)
    print(
        f"object   ADD-S {num(r['add_s_mm'], '.1f')} mm (separate fit {num(r['separate']['add_s_mm'], '.1f')} mm), "
        f"rotation {num(r['rotation_deg'], '.1f')} deg modulo its symmetry (raw {num(r.get('rotation_raw_deg'), '.1f')})"
    )
    print(f"body     MPJPE {num(r['mpjpe_mm'], '.1f')} mm (separate fit {num(r['separate']['mpjpe_mm'], '.1f')} mm)")
    print(
        f"contact  F1 {r['contact_f1']:.2f} ({r['contact_part']}), penetration mean "
        f"{num(r['penetration_mean_mm'], '.1f')} mm, <= 5 mm in {100 * r['penetration_le_5mm']:.0f} % of the "
        "true contact frames"
    )
    print(f"wrote    {', '.join(str(Path(args.out) / f) for f in r['outputs'])}")
    print(f"done in {r['timings_s']['total']:.1f} s")
    return 0


# --- vip ----------------------------------------------------------------------------


def _people(text: str) -> list[int]:
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected person indices separated by commas (e.g. 0,1), got {text!r}"
        ) from None


def _configure_vip(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="vip_action", metavar="ACTION", required=True)
    d = sub.add_parser(
        "demo",
        help="simulate IMU wearers and bystanders filmed by a hand-held camera; fit with VIP",
        description="Simulate a scene from the procedural motion library (no downloads): IMU wearers "
        "(13 IMUs each) and bystanders filmed by a hand-held camera with an IMU, OpenPose-like "
        "detections. Fit it with the Video Inertial Poser (Inertial Tracker, association, fusion, "
        "twice) and write per-wearer npz, overlays, errors over time, a GLB scene and report.json.",
    )
    d.add_argument("--out", required=True, metavar="DIR", help="output folder")
    d.add_argument("--frames", type=_positive(int), default=60, metavar="N", help="frames to simulate (default: 60)")
    d.add_argument("--wearers", type=_positive(int), default=2, metavar="P", help="people wearing IMUs (default: 2)")
    d.add_argument("--bystanders", type=int, default=2, metavar="B", help="people without IMUs (default: 2)")
    d.add_argument("--seed", type=int, default=0, help="seed of the simulation (default: 0)")
    f = sub.add_parser(
        "fit",
        help="fit a 3DPW sequence file (IMUs simulated from its reference poses)",
        description="Fit the Video Inertial Poser to a 3DPW sequence pickle: the chosen people wear "
        "13 IMUs simulated from the file's reference poses, the file's OpenPose detections of "
        "everyone are associated with them; the outputs are those of `jaxmocap vip demo`.",
    )
    f.add_argument("file", help="3DPW sequence file (sequenceFiles/*/name.pkl)")
    f.add_argument("--out", required=True, metavar="DIR", help="output folder")
    f.add_argument("--people", type=_people, metavar="A,B", help="the IMU wearers (default: everyone in the file)")
    f.add_argument(
        "--frames",
        type=_frame_slice,
        metavar="START:STOP",
        help="frames to fit (default: the longest run with a valid camera pose for every wearer)",
    )
    for q in (d, f):
        q.add_argument(
            "--steps", type=_positive(int), default=30, metavar="N", help="LM steps per fusion (default: 30)"
        )
        _add_body_option(q)


def _run_vip(args) -> int:
    from .app.vip import run_vip_demo, run_vip_fit

    log = lambda line: print(line, flush=True)  # noqa: E731
    if args.vip_action == "demo":
        r = run_vip_demo(args.out, frames=args.frames, wearers=args.wearers, bystanders=args.bystanders, seed=args.seed,
                         body=args.body, max_steps=args.steps, log=log)  # fmt: skip
    else:
        r = run_vip_fit(args.file, args.out, people=args.people, frames=args.frames, body=args.body,
                        max_steps=args.steps, log=log)  # fmt: skip
    for k, e in enumerate(r["people"]):
        errors = (
            f", MPJPE IT {e['it_mpjpe_mm']:.1f} mm -> VIP {e['vip_mpjpe_mm']:.1f} mm" if "vip_mpjpe_mm" in e else ""
        )
        print(
            f"wearer {k} (person {e['person']}): {r['association'][-1]['assigned'][k]}/{r['frames']} frames "
            f"assigned{errors}"
        )
    print(f"wrote    {', '.join(str(Path(args.out) / f) for f in r['outputs'])}")
    print(f"done in {r['seconds']['total']:.1f} s")
    return 0


# --- sweep --------------------------------------------------------------------------


def _configure_sweep(p: argparse.ArgumentParser) -> None:
    from .app.sweep import configure_parser

    configure_parser(p)


def _run_sweep(args) -> int:
    from .app.sweep import main_args

    return main_args(args)


# --- prior --------------------------------------------------------------------------


def _configure_prior(p: argparse.ArgumentParser) -> None:
    from .priors.build import configure

    sub = p.add_subparsers(dest="prior_action", metavar="ACTION", required=True)
    configure(sub.add_parser("build", help="fit a Gaussian pose prior to motion folders (AMASS .npz, ASF/AMC, BVH)"))


def _run_prior(args) -> int:
    from .priors.build import run

    return run(args)


COMMANDS: list[Command] = [
    Command("inspect", "summarise a motion file or a body model file", _configure_inspect, _run_inspect),
    Command("convert", "convert any readable motion to an AMASS-style .npz", _configure_convert, _run_convert),
    Command("export", "pose a body with a motion; write meshes (and pictures)", _configure_export, _run_export),
    Command("demo", "walk → posed body → meshes and pictures (the `make demo` job)", _configure_demo, _run_demo),
    Command("check", "physical plausibility: ground penetration, floating, foot skating", _configure_check, _run_check),
    Command(
        "multiview",
        "fit SMPL to multi-camera OpenPose keypoints (Multi-view SMPLify): jaxmocap multiview "
        "PROJECT | demo | --keypoints DIR --calib FILE --out DIR | --videos DIR --calib FILE --out DIR",
        _configure_multiview,
        _run_multiview,
    ),
    Command(
        "interaction",
        "a person handling an object, from RGB-D views (InterCap): jaxmocap interaction demo",
        _configure_interaction,
        _run_interaction,
    ),
    Command(
        "vip",
        "IMU wearers + a hand-held camera (Video Inertial Poser): jaxmocap vip demo | fit FILE.pkl",
        _configure_vip,
        _run_vip,
    ),
    Command(
        "prior", "build a pose prior from your own motion (jaxmocap prior build DIR)", _configure_prior, _run_prior
    ),
    Command("sweep", "grid of methods × weights × sensor errors × datasets, resumable", _configure_sweep, _run_sweep),
]


def build_parser(commands: Sequence[Command] = COMMANDS) -> argparse.ArgumentParser:
    from . import __version__

    parser = argparse.ArgumentParser(prog="jaxmocap", description="Human motion capture in JAX.")
    parser.add_argument("--version", action="version", version=f"jaxmocap {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks instead of one-line errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in commands:
        p = sub.add_parser(command.name, help=command.help, description=command.help)
        command.configure(p)
        p.set_defaults(_run=command.run)
    return parser


def _check_backend() -> None:
    """A JAX_PLATFORMS naming a backend this machine lacks fails at the first array deep in a
    command; find out up front and say so in one line."""
    import os

    platforms = os.environ.get("JAX_PLATFORMS")
    if not platforms:
        return
    import jax

    try:
        jax.devices()
    except (RuntimeError, AssertionError) as e:  # jax 0.10 asserts for an unknown platform
        reason = str(e).splitlines()[0] if str(e) else "no such backend on this machine"
        raise ValueError(
            f"JAX_PLATFORMS={platforms!r}, but JAX cannot start that backend here ({reason}); "
            "unset JAX_PLATFORMS or set it to 'cpu'."
        ) from None


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `jaxmocap` console command; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        _check_backend()
        return int(args._run(args) or 0)
    except (OSError, ValueError, KeyError) as e:
        if args.debug:
            raise
        if isinstance(e, OSError) and e.strerror and e.filename:  # "[Errno 2] ..." → "path: reason"
            message = f"{e.filename}: {e.strerror}"
        else:
            message = str(e) if not isinstance(e, KeyError) else f"missing key {e}"
        print(f"jaxmocap {args.command}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"jaxmocap {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
