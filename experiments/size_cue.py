"""What the shipped IML reads the range from: the robot's pixels of one scene pasted on other
backgrounds (same poses, same robot pixels), and how dark the surroundings of the robot are in
each data set (issue 18's "range read long"; BENCHMARKS.md, "The range is read from the
surroundings, not from the robot alone" and "Dim rooms in training do not take the long range away").

  python experiments/size_cue.py composite --robot A --out OUT [--background B] [--only NAME ...] [--lift-dark L] [--keep-box G] [--evaluate-args=...]
  python experiments/size_cue.py check DATA [DATA ...] --out OUT [--evaluate-args=...]
  python experiments/size_cue.py surround DATA [DATA ...] [--runs EVAL.json ...]
  python experiments/size_cue.py brighten DATA OUT [--target 0.35] [--min-exponent 0.4]

composite: A and B are BOP scenes of the same poses (e.g. the OOD validation sine of seeds 1 and
2). Writes OUT/<name>, a copy of A whose images keep A's robot pixels (its visible mask) on a
background: uniform black (15), grey (110) or white (220), A's own image darkened to 0.35, and,
with --background, B's image as it is and Gaussian-blurred (8 px); then runs `evaluate --modules iml
--zoom-mirror` on each (the shipped networks) and prints, over the detected frames with the robot
in view: |dx| (cm, mean and median), flips, median estimated / true range, detections. The pasted
pixels carry A's shading, so a mismatch of light between robot and room is part of what is tested.
--only keeps the named backgrounds (e.g. "uniform black"); --lift-dark L adds grey to every robot
pixel of luma under L so that its luma is L (the robot's dark parts made visible on any background).
--keep-box G keeps every pixel of the robot's mask's box grown G times about its centre (the robot
with a window of its own room around it; --lift-dark then applies to the whole window).

check: the IML of --evaluate-args (e.g. other networks, or --no-zoom) on BOP sets, composites
written before among them; the same columns, one row per set (runs kept in OUT: a rerun skips them).

surround: per data set (every BOP frame with the robot in view; at most 300 frames, evenly
spaced), the median over frames of the luma (Rec. 601, 0-1) around the robot (its mask's box grown
by half its size each side, the mask excluded) and of the robot's darkest tenth of pixels, and
the share of frames where the surroundings are darker than that tenth plus 0.1, and where both are
dark (surroundings under 0.1, the darkest tenth under 0.05). With --runs (one
`evaluate --json` run per DATA), also the median IML est/true range in each quarter of the frames
by the luma around the robot (detected frames).

brighten: a copy of the BOP set DATA in OUT whose every image is brightened by a gamma curve,
255 (v / 255)^p per channel, p chosen per image to bring its median luma to --target (only
brightening: p in [--min-exponent, 1]); a test-time tone normalisation, to be run through `check`.
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageFilter


def _luma(rgb: np.ndarray) -> np.ndarray:
    return rgb[..., :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32) / 255.0


def _backgrounds(robot: Path, background: Path | None) -> dict:
    """name -> (image file name -> background (H, W, 3) uint8)."""
    rgb = lambda root, n: np.asarray(Image.open(root / n).convert("RGB"))  # noqa: E731
    shape = rgb(robot, next(iter(sorted(robot.iterdir()))).name).shape
    out = {f"uniform {k}": (lambda n, v=v: np.full(shape, v, np.uint8)) for k, v in (("black", 15), ("grey", 110), ("white", 220))}
    out["own room at 0.35"] = lambda n: (rgb(robot, n) * 0.35).astype(np.uint8)
    if background is not None:
        out["other room"] = lambda n: rgb(background, n)
        out["other room, blurred"] = lambda n: np.asarray(Image.open(background / n).convert("RGB").filter(ImageFilter.GaussianBlur(8)))
    return out


def _scene(root: Path) -> Path:
    scenes = sorted(p for p in (root / "test").iterdir() if p.is_dir())
    if len(scenes) != 1:
        raise SystemExit(f"{root}: expected one scene under test/, found {len(scenes)}")
    return scenes[0]


def composite(a) -> None:
    src = _scene(a.robot)
    bgs = _backgrounds(src / "rgb", None if a.background is None else _scene(a.background) / "rgb")
    bgs = {k: v for k, v in bgs.items() if not a.only or k in a.only}
    if a.only and len(bgs) != len(set(a.only)):
        raise SystemExit(f"--only: unknown background name(s) {sorted(set(a.only) - set(bgs))}")
    print("| background | abs dx (cm) mean / median | flips | median est/true range | detected |\n| --- | --- | --- | --- | --- |")
    for name, bg in bgs.items():
        slug = name.replace(" ", "_").replace(",", "").replace(".", "") + (f"_box{a.keep_box:g}" if a.keep_box else "")
        out, js = a.out / slug, a.out / f"{slug}.json"
        if not js.exists():
            shutil.rmtree(out, ignore_errors=True)
            shutil.copytree(a.robot, out, ignore=shutil.ignore_patterns("rgb"))
            dst = _scene(out) / "rgb"
            dst.mkdir()
            for f in sorted((src / "rgb").iterdir()):
                mask = src / "mask_visib" / f"{f.stem}_000000.png"
                img = bg(f.name).copy()
                if mask.exists():
                    m = np.asarray(Image.open(mask)) > 0
                    if a.keep_box and m.any():  # the robot's box grown about its centre: all its pixels kept
                        m = _grown_box(m, a.keep_box)
                    px = np.asarray(Image.open(f).convert("RGB")).astype(np.float32)
                    if a.lift_dark > 0:
                        px = px + np.maximum(0.0, 255.0 * a.lift_dark - _luma(px) * 255.0)[..., None]
                    img[m] = np.clip(px[m] + 0.5, 0, 255).astype(np.uint8)
                Image.fromarray(img).save(dst / f.name)
        print(_iml_row(name, out, js, a.evaluate_args), flush=True)


def _grown_box(m: np.ndarray, grow: float) -> np.ndarray:
    """(H, W) bool: the box of mask m grown `grow` times about its centre (clipped to the image)."""
    ys, xs = np.nonzero(m)
    cy, cx = 0.5 * (ys.min() + ys.max() + 1), 0.5 * (xs.min() + xs.max() + 1)
    hy, hx = 0.5 * grow * (ys.max() + 1 - ys.min()), 0.5 * grow * (xs.max() + 1 - xs.min())
    out = np.zeros_like(m)
    out[max(0, int(round(cy - hy))):int(round(cy + hy)), max(0, int(round(cx - hx))):int(round(cx + hx))] = True
    return out


def _iml_row(name: str, data: Path, js: Path, evaluate_args: str) -> str:
    """Runs the IML on `data` (unless `js` holds the run) and gives its table row."""
    from rhaml_jax.metrics import frame_summary

    if not js.exists():
        extra = shlex.split(evaluate_args)
        mirror = [] if "--no-zoom" in extra else ["--zoom-mirror"]
        cmd = [sys.executable, "-m", "rhaml_jax.evaluate", "--data", str(data), "--modules", "iml", *mirror, "--json", str(js), *extra]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    s = frame_summary([dict(r, est=r["iml_est"]) for r in json.loads(js.read_text())["frames"]])
    return (f"| {name} | {s['dx_cm'][0]:.1f} / {s['dx_cm'][2]:.1f} | {s['flips']} / {s['n']} | "
            f"{s['median_range_ratio']:.3f} | {s['detection']['tp']} of {s['detection']['tp'] + s['detection']['fn']} |")


def check(a) -> None:
    """One set of networks (--evaluate-args) on composites written earlier and on other BOP sets."""
    a.out.mkdir(parents=True, exist_ok=True)
    print("| data | abs dx (cm) mean / median | flips | median est/true range | detected |\n| --- | --- | --- | --- | --- |")
    for d in a.data:
        print(_iml_row(str(d), d, a.out / (str(d).strip("/").replace("/", "_") + ".json"), a.evaluate_args), flush=True)


def surround(a) -> None:
    from rhaml_jax.data import read_bop

    if a.runs and len(a.runs) != len(a.data):
        raise SystemExit(f"--runs: {len(a.runs)} runs for {len(a.data)} data sets (one per DATA)")
    print("| data | frames | luma around the robot | the robot's darkest tenth | surroundings darker than it + 0.1 | both dark |"
          f"{' IML range ratio by quarter of the luma around |' if a.runs else ''}\n"
          f"| --- | --- | --- | --- | --- | --- |{' --- |' if a.runs else ''}")
    for i, root in enumerate(a.data):
        rows = json.loads(a.runs[i].read_text())["frames"] if a.runs else None
        frames = [(k, f) for k, f in enumerate(read_bop(root)) if f.mask is not None]
        frames = [frames[j] for j in np.unique(np.linspace(0, len(frames) - 1, min(300, len(frames))).astype(int))]
        around, dark, ratio = [], [], []
        for k, f in frames:
            m = np.asarray(Image.open(f.mask)) > 0
            if m.sum() < 20:
                continue
            y = _luma(np.asarray(Image.open(f.rgb).convert("RGB")))
            ys, xs = np.nonzero(m)
            h, w = ys.max() - ys.min() + 1, xs.max() - xs.min() + 1
            box = np.zeros_like(m)
            box[max(0, ys.min() - h // 2): ys.max() + h // 2 + 1, max(0, xs.min() - w // 2): xs.max() + w // 2 + 1] = True
            around.append(float(np.median(y[box & ~m])))
            dark.append(float(np.percentile(y[m], 10)))
            r = rows[k] if rows else None
            ratio.append(np.hypot(*r["iml_est"][:2]) / np.hypot(*r["gt"][:2]) if r and r["detected"] else np.nan)
        around, dark, ratio = np.array(around), np.array(dark), np.array(ratio)
        cells = ""
        if rows:
            q = np.quantile(around, [0.25, 0.5, 0.75])
            part = np.searchsorted(q, around)
            cells = " " + ", ".join(f"{np.nanmedian(ratio[part == j]):.3f}" for j in range(4)) + " |"
        print(f"| {root} | {len(around)} | {np.median(around):.3f} | {np.median(dark):.3f} | "
              f"{np.mean(around < dark + 0.1):.0%} | {np.mean((around < 0.1) & (dark < 0.05)):.0%} |{cells}", flush=True)


def brighten(a) -> None:
    if a.out.exists():
        raise SystemExit(f"{a.out}: exists; brighten writes a new copy")
    shutil.copytree(a.data, a.out, ignore=shutil.ignore_patterns("rgb"))
    for rgb in sorted(a.data.glob("test/*/rgb")):
        dst = a.out / rgb.relative_to(a.data)
        dst.mkdir()
        exps = []
        for f in sorted(rgb.iterdir()):
            rgb8 = np.asarray(Image.open(f).convert("RGB"))
            x = rgb8.astype(np.float32) / 255.0
            m = max(float(np.median(_luma(rgb8))), 1e-3)  # guard: log(0) for a black image
            exps.append(float(np.clip(np.log(a.target) / np.log(m), a.min_exponent, 1.0)))
            Image.fromarray((255.0 * x ** exps[-1] + 0.5).astype(np.uint8)).save(dst / f.name)
        print(f"{rgb}: exponent median {np.median(exps):.2f}, min {np.min(exps):.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("composite")
    c.add_argument("--robot", type=Path, required=True)
    c.add_argument("--background", type=Path)
    c.add_argument("--out", type=Path, required=True)
    c.add_argument("--evaluate-args", default="")
    c.add_argument("--only", nargs="+", default=[])
    c.add_argument("--lift-dark", type=float, default=0.0)
    c.add_argument("--keep-box", type=float, default=0.0, help="keep the robot's box grown this many times (room included)")
    k = sub.add_parser("check")
    k.add_argument("data", type=Path, nargs="+")
    k.add_argument("--out", type=Path, required=True)
    k.add_argument("--evaluate-args", default="")
    s = sub.add_parser("surround")
    s.add_argument("data", type=Path, nargs="+")
    s.add_argument("--runs", type=Path, nargs="+", default=[])
    b = sub.add_parser("brighten")
    b.add_argument("data", type=Path)
    b.add_argument("out", type=Path)
    b.add_argument("--target", type=float, default=0.35)
    b.add_argument("--min-exponent", type=float, default=0.4)
    a = ap.parse_args()
    {"composite": composite, "check": check, "surround": surround, "brighten": brighten}[a.cmd](a)


if __name__ == "__main__":
    main()
