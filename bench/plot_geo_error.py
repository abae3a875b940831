"""The range error model as a PNG for docs/mavlink.md, from ``glad-payload geo-error --json``.

  python bench/plot_geo_error.py /tmp/geo/truth.json /tmp/geo/glad.json --out docs/img/range_error.png

One panel: |range error| / range against the box size in pixels, every sample as a dot (one
colour per JSON: truth boxes, GLAD's boxes), the median and 95th percentile per octave of box
size as lines, and the payload's 1-sigma model hypot(size_noise_px / s, shape_uncertainty) (and
the bound above which geo outputs are withheld) for reference. matplotlib is needed only here.
"""

import argparse
import json

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

EDGES = np.array([4, 6, 8, 11, 16, 23, 32, 45, 64, 90, 128], float)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("json", nargs="+", help="geo-error --json outputs")
    p.add_argument("--out", required=True, help="PNG to write")
    args = p.parse_args()
    fig, ax = plt.subplots(figsize=(8, 5), dpi=110)
    colours = ["tab:blue", "tab:orange", "tab:green"]
    target = None
    for path, colour in zip(args.json, colours):
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
        target = data["settings"]["target"]
        size = np.array([s["size_px"] for s in data["samples"]])
        rel = np.array([abs(s["range_est_m"] - s["range_m"]) / s["range_m"] for s in data["samples"]])
        label = "%s boxes (%d frames)" % (data["settings"]["boxes"], len(size))
        ax.scatter(size, 100 * rel, s=4, alpha=0.25, color=colour, label=label)
        mids, med, p95 = [], [], []
        for lo, hi in zip(EDGES[:-1], EDGES[1:]):
            sel = rel[(size >= lo) & (size < hi)]
            if len(sel) >= 10:
                mids.append(np.sqrt(lo * hi))
                med.append(100 * np.median(sel))
                p95.append(100 * np.percentile(sel, 95))
        ax.plot(mids, med, "-o", color=colour, lw=2, ms=4, label="  median")
        ax.plot(mids, p95, "--", color=colour, lw=1.5, label="  95th percentile")
    if target is not None:
        s = np.geomspace(4, 128, 100)
        model = 100 * np.hypot(target["size_noise_px"] / s, target["shape_uncertainty"])
        ax.plot(s, model, color="black", lw=1, label="model 1 sigma: hypot(%.1f px / s, %.2f)"
                % (target["size_noise_px"], target["shape_uncertainty"]))
        ax.axhline(100 * target["max_relative_uncertainty"], color="grey", ls=":", lw=1,
                   label="geo outputs withheld above sigma/range = %.2f" % target["max_relative_uncertainty"])
    ax.set_xscale("log")
    ax.set_xticks([4, 8, 16, 32, 64, 128])
    ax.set_xticklabels(["4", "8", "16", "32", "64", "128"])
    ax.set_ylim(0, 80)
    ax.set_xlabel("box size (longer side), px")
    ax.set_ylabel("|range error| / range, %")
    ax.set_title("Range from apparent size on synthetic scenes of known geometry")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(args.out)
    print("wrote %s" % args.out)


if __name__ == "__main__":
    main()
