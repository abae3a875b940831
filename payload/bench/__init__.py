"""``glad-payload bench``: speed profile, ablation (the paper's Table V) and baselines.

- runners: what a row runs per frame (GLAD, or a baseline detector) behind one ``process(frame)``;
- profile: per-module time, FPS with/without decoding, capture-to-MAVLink latency on one clip;
- ablation: P/R/F/AP and FPS per configuration over a split of clips;
- cli: argument handling and the text/JSON reports.
"""
