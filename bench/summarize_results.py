"""Markdown tables for docs/results.md from the JSON files of bench/run_results.sh.

  python bench/summarize_results.py bench-results [--before OLD_RESULTS]
"""

import argparse
import glob
import json
import os


def _load(path):
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def _f(v, digits=1):
    return "-" if v is None else "%.*f" % (digits, v)


def profile_table(folder, before=None):
    paths = sorted(glob.glob(os.path.join(folder, "profile_*.json")))
    lines = ["| clip | runner | size | frames | FPS e2e | FPS w/o decode | decode-only FPS | ratio | p50 ms | p99 ms |"
             + (" FPS e2e before | p99 ms before |" if before else ""),
             "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |" + (" ---: | ---: |" if before else "")]
    for path in paths:
        r = _load(path)
        row = "| %s | %s | %dx%d | %d | %s | %s | %s | %s | %s | %s |" % (
            os.path.basename(r["source"]).replace(".mp4", ""), r["runner"], r["size_wh"][0], r["size_wh"][1],
            r["frames"], _f(r["fps_end_to_end"]), _f(r["fps_without_decode"]), _f(r["fps_decode_only"], 0),
            _f(r["decode_ratio"], 2), _f(r["latency_p50_ms"]), _f(r["latency_p99_ms"]))
        if before:
            old = os.path.join(before, os.path.basename(path))
            if os.path.isfile(old):
                o = _load(old)
                row += " %s | %s |" % (_f(o["fps_end_to_end"]), _f(o["latency_p99_ms"]))
            else:
                row += " | |"
        lines.append(row)
    return "\n".join(lines)


def modules_table(path):
    r = _load(path)
    lines = ["| module | runs | share % | median ms | p95 ms | mean ms |", "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for m in r["modules"]:
        lines.append("| %s | %d | %.1f | %.2f | %.2f | %.2f |" % (m["name"], m["runs"], 100 * m["share"], m["median_ms"],
                                                               m["p95_ms"], m["mean_ms"]))
    return "\n".join(lines)


def ablation_table(path):
    d = _load(path)
    lines = ["| configuration | P | R | F | AP | frames with a detection % | FPS detector | FPS incl. decode |"
             " modules ran (frames) |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |"]
    for r in d["rows"]:
        p = r["pooled"]
        runs = " ".join("%s=%d" % kv for kv in sorted(r["module_runs"].items()))
        det = p["frames_with_detections"]
        lines.append("| %s | %s | %s | %s | %s | %s | %s | %s | %s |" % (
            r["name"], _f(p["precision"], 3), _f(p["recall"], 3), _f(p["f1"], 3), _f(p["ap"], 3),
            _f(None if det is None else 100 * det), _f(r["fps_detect"]), _f(r["fps_end_to_end"]), runs))
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("folder")
    ap.add_argument("--before", default=None)
    args = ap.parse_args()
    print("## profiles\n")
    print(profile_table(args.folder, args.before))
    for name in ("profile_V_DRONE_013.json", "profile_syn1080_glad.json"):
        path = os.path.join(args.folder, name)
        if os.path.isfile(path):
            print("\n## modules %s\n" % name)
            print(modules_table(path))
    for name in ("ablation_val.json", "ablation_negatives_val.json", "ablation_syn1080.json"):
        path = os.path.join(args.folder, name)
        if os.path.isfile(path):
            print("\n## %s\n" % name)
            print(ablation_table(path))


if __name__ == "__main__":
    main()
