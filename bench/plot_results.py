"""PNG plots for docs/results.md from the JSON that ``glad-payload bench`` writes.

  python bench/plot_results.py --ablation ablation.json --profiles a.json b.json --out docs/img
  python bench/plot_results.py --pr pr_val.json --pr-title "Halmstad val" --out docs/img/pr_val.png
Writes fps_per_configuration.png (ablation rows: detector-only and end-to-end FPS, with AP)
and time_per_module.png (mean ms per frame of each module, one group per profile); with --pr,
one precision-recall curve per ablation row (or eval JSON) with its operating points marked.
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


def plot_pr(files, title, out_png, rows=None, marks=(0.1, 0.3, 0.5, 0.7)):
    """PR curves of every row of ablation JSONs (or the pooled row of eval JSONs); the points where the
    score threshold crosses ``marks`` are labelled, so the chosen T0/T1 can be read off the curve."""
    fig, ax = plt.subplots(figsize=(6, 4.5))
    seen = set()  # a row name in several files: the first file's curve is drawn
    for path in files:
        data = _load(path)
        rows_of = data["rows"] if "rows" in data else [{"name": data["pooled"]["name"], "pooled": data["pooled"]}]
        for r in rows_of:
            if (rows and r["name"] not in rows) or r["name"] in seen:
                continue
            seen.add(r["name"])
            curve = np.array(r["pooled"].get("pr_curve") or [], float).reshape(-1, 3)
            if not len(curve):
                continue
            line, = ax.plot(curve[:, 2], curve[:, 1], lw=1.5, label="%s (AP %.2f)" % (r["name"], r["pooled"]["ap"] or 0))
            for t in marks:
                kept = curve[curve[:, 0] >= t]
                if len(kept):
                    ax.plot(kept[-1, 2], kept[-1, 1], "o", ms=4, color=line.get_color())
                    ax.annotate("%.1f" % t, (kept[-1, 2], kept[-1, 1]), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("recall (IoU > 0.5)")
    ax.set_ylabel("precision")
    ax.set_title("%s: precision-recall (dots: score thresholds)" % title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(out_png, dpi=90)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ablation")
    ap.add_argument("--profiles", nargs="+", default=[])
    ap.add_argument("--pr", nargs="+", default=[], help="ablation/eval JSONs: PR curves into --out (a .png path)")
    ap.add_argument("--pr-title", default="")
    ap.add_argument("--pr-rows", nargs="*", default=None, help="only these ablation rows")
    ap.add_argument("--out", default="docs/img")
    args = ap.parse_args()
    if args.pr:
        plot_pr(args.pr, args.pr_title, args.out, rows=args.pr_rows)
        print("wrote %s" % args.out)
        return
    os.makedirs(args.out, exist_ok=True)
    plot_ablation(_load(args.ablation), os.path.join(args.out, "fps_per_configuration.png"))
    plot_modules([_load(p) for p in args.profiles], os.path.join(args.out, "time_per_module.png"))
    print("wrote %s" % args.out)


if __name__ == "__main__":
    main()
