"""PNG plots for docs/results.md from the JSON that ``glad-payload bench`` writes.

  python bench/plot_results.py --ablation ablation.json --profiles a.json b.json --out docs/img
Writes fps_per_configuration.png (ablation rows: detector-only and end-to-end FPS, with AP)
and time_per_module.png (mean ms per frame of each module, one group per profile).
matplotlib is needed only here (pip install matplotlib), never by the payload.
"""

import argparse
import json
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def _load(path):
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def plot_ablation(data, out_png):
    rows = data["rows"]
    names = [r["name"] for r in rows]
    y = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(8, 0.45 * len(rows) + 1.2))
    ax.barh(y - 0.2, [r["fps_detect"] or 0 for r in rows], 0.4, label="detector only")
    ax.barh(y + 0.2, [r["fps_end_to_end"] or 0 for r in rows], 0.4, label="incl. decoding")
    for i, r in enumerate(rows):
        ap = r["pooled"]["ap"]
        ax.text(max(r["fps_detect"] or 0, r["fps_end_to_end"] or 0) + 2, i, "AP %.2f" % ap if ap is not None else "AP -",
                va="center", fontsize=8)
    ax.set_yticks(y, names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("frames per second (%d clips, %d frames)" % (len(data["clips"]), rows[0]["frames"]))
    ax.axvline(23.6, color="grey", ls=":", lw=1)
    ax.text(23.6, len(rows) - 0.4, " paper, Xavier NX", fontsize=7, color="grey")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(out_png, dpi=90)
    plt.close(fig)


def plot_modules(profiles, out_png):
    names = []
    for p in profiles:
        names += [m["name"] for m in p["modules"] if m["name"] not in names]
    fig, ax = plt.subplots(figsize=(8, 3.2))
    width = 0.8 / len(profiles)
    x = np.arange(len(names))
    for i, p in enumerate(profiles):
        per_frame = {m["name"]: m["mean_ms"] * m["share"] for m in p["modules"]}
        label = "%s %dx%d (%.0f fps)" % (os.path.basename(p["source"]), p["size_wh"][0], p["size_wh"][1],
                                         p["fps_end_to_end"])
        ax.bar(x + (i - (len(profiles) - 1) / 2) * width, [per_frame.get(n, 0) for n in names], width, label=label)
    ax.set_xticks(x, names, fontsize=8, rotation=30)
    ax.set_ylabel("ms per frame (mean x share of frames)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out_png, dpi=90)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ablation", required=True)
    ap.add_argument("--profiles", nargs="+", required=True)
    ap.add_argument("--out", default="docs/img")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    plot_ablation(_load(args.ablation), os.path.join(args.out, "fps_per_configuration.png"))
    plot_modules([_load(p) for p in args.profiles], os.path.join(args.out, "time_per_module.png"))
    print("wrote %s" % args.out)


if __name__ == "__main__":
    main()
