"""The work behind `jaxmocap check MOTION`: report table, plot and contact heat map."""

from __future__ import annotations

from pathlib import Path

__all__ = ["run_check"]


def run_check(motion_path, body="default-low", fps=None, ground="0", out=None) -> int:
    """Print the plausibility report of a motion file; with `out`, write the PNG and PLY."""
    from ..motion.io import load_motion
    from ..body.io import resolve_body
    from ..physics.mjcf import Ground
    from ..physics.report import format_report, plausibility_report, plot_report

    if out is not None:
        # Before minutes of work, not after: an output folder that cannot be made.
        try:
            Path(out).mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise OSError(e.errno, f"cannot create the output folder --out {out}: {e.strerror}", str(out)) from e
    if ground != "auto":
        try:
            ground = Ground(float(ground))
        except ValueError:
            raise ValueError(f"--ground must be a height in metres or 'auto', got {ground!r}.") from None
    body = resolve_body(body)
    motion = load_motion(motion_path, fps=fps, body=body)
    report = plausibility_report(body, motion, ground=ground)
    print(format_report(report))
    if out is not None:
        from ..viz.mesh import export_mesh

        stem = Path(motion_path).stem
        png = plot_report(report, Path(out) / f"{stem}_check.png")
        import numpy as np

        ply = export_mesh(
            np.asarray(body.v_template),
            body.faces,
            Path(out) / f"{stem}_contact_heatmap.ply",
            colors=report.heatmap,
            vmin=0.0,
            vmax=max(float(report.heatmap.max()), 1e-6),
        )
        print(f"wrote {png}")
        print(f"wrote {ply} (rest mesh coloured by ground-contact frequency, 4.5 mm)")
    return 0
