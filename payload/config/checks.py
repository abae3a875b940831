"""What ``run`` needs from the files and folders a valid config names, checked before it starts.

``load_run_config(path)`` is what ``glad-payload run``, its SIGHUP reload and
``glad-payload check-config`` all call, so that check-config accepts exactly the files that run
accepts: the signing key readable and 32 bytes, the outputs folder creatable and writable, the
recording (capture.path) and the model files present. One line per problem, pointing into the
config file like the schema's messages. Devices are not opened and models are not loaded.
"""

import os
import tempfile
from typing import List, Optional, Tuple

from payload.config.loading import parse_config, problem_line, read_yaml
from payload.config.reload import changed_keys
from payload.config.schema import Config
from payload.errors import ConfigError


def load_signing_key(path: str) -> bytes:
    """The 32-byte signing key from a file holding 32 raw bytes or 64 hex characters."""
    try:
        with open(path, "rb") as fh:
            data = fh.read(4096)  # a key file is 32 or ~65 bytes: read no more than a page
    except OSError as exc:
        raise ConfigError(["mavlink.signing.key_file=%s: cannot read: %s" % (path, exc.strerror or exc)]) from None
    if len(data) == 32:
        return data
    text = data.strip()
    if len(text) == 64:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    raise ConfigError(["mavlink.signing.key_file=%s: expected 32 raw bytes or 64 hex characters, got %d bytes"
                       % (path, len(data))])


def path_problem(path: str, want_dir: bool) -> Optional[str]:
    """Why ``path`` is not an existing folder (want_dir) or file, or None."""
    if not os.path.exists(path):
        return "%s: no such %s" % (path, "folder" if want_dir else "file")
    if want_dir and not os.path.isdir(path):
        return "%s: is a file, expected a folder" % path
    if not want_dir and os.path.isdir(path):
        return "%s: is a folder, expected a file" % path
    return None


def writable_dir_problem(path: str) -> Optional[str]:
    """Why files cannot be written in folder ``path`` (created as run would create it), or None.

    Tried for real (root may write where the mode bits say no, and /proc says yes to access());
    folders made for the try are removed again."""
    target = os.path.abspath(path)
    missing = []
    existing = target
    while not os.path.lexists(existing):
        missing.append(existing)
        parent = os.path.dirname(existing)
        if parent == existing:
            break
        existing = parent
    if not os.path.isdir(existing):
        return "%r: %s is not a folder" % (path, existing)
    created: List[str] = []
    doing = "cannot create the folder"
    try:
        for folder in reversed(missing):
            os.mkdir(folder)
            created.append(folder)
        doing = "cannot write files there"
        fd, probe = tempfile.mkstemp(dir=target, prefix=".glad-payload-check-")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        return "%r: %s: %s" % (path, doing, exc.strerror or exc)
    finally:
        for folder in reversed(created):
            try:
                os.rmdir(folder)
            except OSError:
                pass
    return None


def file_problems(cfg: Config) -> List[Tuple[Tuple, str]]:
    """(config location, message) for each file or folder ``run`` would fail on."""
    out: List[Tuple[Tuple, str]] = []
    cap = cfg.capture
    if cap.source in ("file", "folder") and cap.path:
        problem = path_problem(cap.path, want_dir=cap.source == "folder")
        if problem:
            out.append((("capture", "path"), problem))
    if cap.source == "synthetic" and cap.synthetic.background:
        problem = path_problem(cap.synthetic.background, want_dir=False)
        if problem:
            out.append((("capture", "synthetic", "background"), problem))
    signing = cfg.mavlink.signing
    if cfg.mavlink.enabled and signing.enabled and signing.key_file:
        try:
            load_signing_key(signing.key_file)
        except ConfigError as exc:
            out.append((("mavlink", "signing", "key_file"), exc.problems[0].split("=", 1)[1]))
    if cfg.outputs.directory:
        problem = writable_dir_problem(cfg.outputs.directory)
        if problem:
            out.append((("outputs", "directory"), problem))
    det = cfg.detector
    models = [(("detector", "global", "appearance", "model"), det.global_.appearance),
              (("detector", "local", "appearance", "model"), det.local.appearance),
              (("detector", "classifier", "model"), det.classifier),
              (("detector", "verifier", "model"), det.verifier)]
    for loc, section in models:
        if section.enabled and section.model:
            problem = path_problem(section.model, want_dir=False)
            if problem:
                out.append((loc, problem))
    return out


def load_run_config(path: Optional[str], running: Optional[Config] = None) -> Config:
    """``load_config`` plus the file checks: the config ``run`` starts with. For a reload pass the
    ``running`` config: then only the files of keys that changed are checked (an outputs folder
    that filled up since the start must not block a reload of the thresholds)."""
    if path is None:
        return Config()
    data, lines = read_yaml(path)
    cfg = parse_config(data, source=path, lines=lines)
    found = file_problems(cfg)
    if running is not None:
        changed = set(changed_keys(running, cfg))
        found = [(loc, message) for loc, message in found if ".".join(loc) in changed]
    problems = [problem_line(path, lines, loc, message) for loc, message in found]
    if problems:
        raise ConfigError(problems)
    return cfg
