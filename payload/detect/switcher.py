"""The detector switcher (paper Sec. III): global until a hit, local while hits continue,
back to global after N consecutive local misses."""

from payload.config import SwitcherConfig

GLOBAL = "global"
LOCAL = "local"


class Switcher:
    def __init__(self, cfg: SwitcherConfig, local_available: bool = True) -> None:
        self.cfg = cfg
        self.local_available = local_available  # False when both local modules are switched off
        self.mode = GLOBAL
        self.local_misses = 0

    def update_config(self, cfg: SwitcherConfig) -> None:
        self.cfg = cfg

    def reset(self) -> None:
        self.mode = GLOBAL
        self.local_misses = 0

    def after(self, hit: bool) -> str:
        """Record this frame's outcome; return the mode for the next frame."""
        if hit:
            self.local_misses = 0
            self.mode = LOCAL if self.local_available else GLOBAL
        elif self.mode == LOCAL:
            self.local_misses += 1
            if self.local_misses >= self.cfg.max_local_misses:
                self.reset()
        return self.mode
