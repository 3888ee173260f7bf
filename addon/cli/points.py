"""``points-to-capture``: a capture from a folder of calibrated point clouds (``core.footage.point_clouds``)."""

from __future__ import annotations

from .common import add_command, force_arg


def cmd_points_to_capture(a):
    from ..core.footage.point_clouds import points_to_capture, read_setup
    from .common import refuse_filled_folder

    refuse_filled_folder(a.out, a.force)
    setup = read_setup(a.setup, frame_interval=a.frame_interval, splat_radius=a.splat_radius)
    cap, report = points_to_capture(a.points, setup, a.out)
    left = f", {len(report['left_out'])} left out (too few points above the crop)" if report["left_out"] else ""
    print(f"wrote capture {a.out}: {cap.n_cameras} cameras x {cap.n_frames} frames{left}")
    if report["splat_floor_pct"] is not None:
        print(
            f"the splatting's own error: {report['splat_floor_pct']:.1f} % E_sil per image (what a perfect model "
            f"keeps against these silhouettes: the floor a fit is judged against)"
        )
    return report


def add_points(sub):
    """``points-to-capture``: silhouettes splatted from point clouds, the robot's path as the handle."""
    s = add_command(
        sub,
        "points-to-capture",
        cmd_points_to_capture,
        "make a capture from a folder of point clouds (one N x 3 .npy per frame)",
        "the capture, its cameras, frame times, the frames left out, the splat radius, the splatting's own error and the "
        "crop as JSON",
    )
    s.add_argument("points", help="folder of point clouds: one N x 3 .npy per frame, in name order")
    s.add_argument(
        "setup",
        help="setup JSON: unit_scale, frame_interval, splat_radius, cloth, path, crop, cameras "
        "(docs/point_clouds.md, 'The setup file')",
    )
    s.add_argument("--out", required=True, help="capture folder to write (new or empty unless --force)")
    force_arg(s, "the files of a capture already in --out")
    s.add_argument("--frame-interval", type=float, help="seconds between frames (default: the setup's)")
    s.add_argument(
        "--splat-radius", type=float, help="radius [m] of the disc drawn for each point (default: the setup's)"
    )
