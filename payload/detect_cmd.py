"""``glad-payload detect``: GLAD over a recording, one CSV row per detection."""

from payload.annotate import VideoOut, draw_result
from payload.config import load_config
from payload.offline import iter_glad
from payload.records import DetectionsCsvWriter


def main_detect(args) -> int:
    cfg = load_config(args.config)
    video = VideoOut(args.video) if args.video else None
    frames = hits = 0
    with DetectionsCsvWriter(args.out) as writer:
        try:
            for frame, result in iter_glad(args.source, cfg, progress=not args.no_progress):
                writer.write_result(frame.index, result)  # every reported target, the primary flagged
                frames += 1
                hits += bool(len(result.detections))
                if video is not None:
                    video.write(draw_result(frame.image, result))
        finally:
            if video is not None:
                video.close()
    print("%s: %d frames, %d with a detection -> %s" % (args.source, frames, hits, args.out))
    return 0
