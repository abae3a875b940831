"""Reading a config file: bounded input, YAML, one operator-readable line per problem.

``load_config(path)`` returns a ``Config`` or raises ``ConfigError`` whose ``problems`` are one
line each, in the form ``FILE:LINE: dotted.key: value ... rule`` so that a field operator can
fix the file. The input is bounded before anything is built from it: at most ``MAX_BYTES``,
UTF-8, one YAML document whose tree, with every alias expanded, has at most ``MAX_NODES``
nodes (a "billion laughs" file of a few lines would otherwise expand to gigabytes in the
validator), no recursive alias, no number of more than ``MAX_DIGITS`` digits.
"""

import difflib
from typing import Any, Dict, List, Optional, Tuple

import yaml
from annotated_types import Ge, Gt, Le, Lt
from pydantic import BaseModel, ValidationError
from typing_extensions import get_args

from payload.config.schema import Config
from payload.errors import ConfigError

#: Largest config file read (the shipped default.yaml, every key documented, is ~11 kB).
MAX_BYTES = 1 << 20
#: Largest YAML tree, counted with aliases expanded (the full config has ~250 nodes).
MAX_NODES = 20_000
#: Longest integer literal (YAML ints are unbounded; converting a long one costs quadratic time).
MAX_DIGITS = 100


class _Loader(yaml.SafeLoader):
    """yaml.SafeLoader with bounded integers."""

    def construct_yaml_int(self, node):
        digits = sum(c.isdigit() for c in str(node.value))
        if digits > MAX_DIGITS:
            raise yaml.constructor.ConstructorError(
                None, None, "a number of %d digits (at most %d)" % (digits, MAX_DIGITS), node.start_mark)
        return super().construct_yaml_int(node)


_Loader.add_constructor("tag:yaml.org,2002:int", _Loader.construct_yaml_int)


def _children(node: yaml.Node) -> List[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


def _expanded_size_problem(root: yaml.Node) -> Optional[str]:
    """Why the tree is too big once aliases are expanded (or recursive), else None.

    Composing keeps an alias as a second reference to its anchor's node, so the file's graph is
    small; the size with aliases expanded is counted over that graph, once per node (memo)."""
    size: Dict[int, int] = {}
    on_path = set()
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            on_path.discard(key)
            size[key] = 1 + sum(size[id(c)] for c in _children(node))
            if size[key] > MAX_NODES:
                return ("holds more than %d values once its aliases (*name) are expanded (at most %d): "
                        "write the values out" % (MAX_NODES, MAX_NODES))
            continue
        if key in size:
            continue
        if key in on_path:
            return "a recursive alias (an anchor used inside itself) near line %d" % (node.start_mark.line + 1)
        on_path.add(key)
        stack.append((node, True))
        for child in _children(node):
            if id(child) in on_path:
                return "a recursive alias (an anchor used inside itself) near line %d" % (child.start_mark.line + 1)
            if id(child) not in size:
                stack.append((child, False))
    return None


def _line_map(root: yaml.Node) -> Dict[Tuple, int]:
    """Each YAML key path (scalar keys only) -> its 1-based line, so errors can point into the file."""
    lines: Dict[Tuple, int] = {}
    stack = [(root, ())]
    while stack:  # bounded: the expanded tree has at most MAX_NODES nodes
        node, path = stack.pop()
        if isinstance(node, yaml.MappingNode):
            for key_node, value_node in node.value:
                if isinstance(key_node, yaml.ScalarNode):
                    p = path + (key_node.value,)
                    lines.setdefault(p, key_node.start_mark.line + 1)
                    stack.append((value_node, p))
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                lines.setdefault(path + (i,), item.start_mark.line + 1)
                stack.append((item, path + (i,)))
    return lines


def _yaml_problem(exc: yaml.YAMLError) -> Tuple[Optional[int], str]:
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None)
    if isinstance(exc, yaml.reader.ReaderError):  # a character YAML does not allow
        char = exc.character if isinstance(exc.character, int) else ord(exc.character[:1] or "\0")
        return None, "character U+%04X at position %d is not allowed in YAML" % (char, exc.position)
    context = getattr(exc, "context", None)
    if problem and context:
        problem = "%s, %s" % (context, problem)
    text = problem or (str(exc).splitlines() or [type(exc).__name__])[0]
    return (mark.line + 1 if mark is not None else None), text


def read_yaml(path: str) -> Tuple[Any, Dict[Tuple, int]]:
    """The YAML document of a file (bounded as the module doc says) and its line map."""
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_BYTES + 1)
    except OSError as exc:
        raise ConfigError(["%s: cannot read config file: %s" % (path, exc.strerror or exc)]) from None
    if len(raw) > MAX_BYTES:
        raise ConfigError(["%s: larger than %d bytes (1 MiB), the most a config file may hold" % (path, MAX_BYTES)])
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise ConfigError(["%s:%d: not UTF-8 text (byte 0x%02x at offset %d): save the file as UTF-8"
                           % (path, line, raw[exc.start], exc.start)]) from None
    if not text.strip():
        raise ConfigError(["%s: the file is empty: expected sections such as capture:, detector:, mavlink: "
                           "(configs/default.yaml lists every key)" % path])
    loader = None
    try:
        loader = _Loader(text)
        root = loader.get_single_node()
        if root is None:
            raise ConfigError(["%s: the file holds only comments: expected sections such as capture:, detector:, "
                               "mavlink: (configs/default.yaml lists every key)" % path])
        problem = _expanded_size_problem(root)
        if problem is not None:
            raise ConfigError(["%s: %s" % (path, problem)])
        data = loader.construct_document(root)
        return data, _line_map(root)
    except yaml.YAMLError as exc:
        line, problem = _yaml_problem(exc)
        where = "%s:%d" % (path, line) if line else path
        raise ConfigError([_one_line("%s: not valid YAML: %s" % (where, problem))]) from None
    except RecursionError:
        raise ConfigError(["%s: not valid YAML: nested too deeply" % path]) from None
    except ValueError as exc:  # a constructor's own conversion (e.g. a float or date out of range)
        raise ConfigError([_one_line("%s: not valid YAML: %s" % (path, exc))]) from None
    finally:
        if loader is not None:
            loader.dispose()


# --- error messages -------------------------------------------------------------------------


def _one_line(text: str) -> str:
    return " ".join(str(text).splitlines())


def _field_for(loc: Tuple) -> Tuple[Optional[Any], Optional[type]]:
    """The pydantic FieldInfo at a location, and the model that holds it."""
    model: Any = Config
    info = None
    owner = None
    for part in loc:
        if not (isinstance(model, type) and issubclass(model, BaseModel)):
            return info, None
        fields = model.model_fields
        name = next((n for n, f in fields.items() if n == part or f.alias == part), None)
        if name is None:
            return None, model
        info = fields[name]
        owner = model
        model = info.annotation
    return info, owner


def _bounds(info, item: bool = False) -> Tuple[Optional[float], Optional[float], str, str]:
    lo = hi = None
    lo_op, hi_op = "[", "]"
    metadata = list(getattr(info, "metadata", []))
    if item:  # an element of a list field: the bounds of List[Annotated[int, Field(...)]]'s item type
        args = get_args(getattr(info, "annotation", None))
        metadata = []
        for arg in get_args(args[0]) if args else ():
            metadata.extend(getattr(arg, "metadata", [arg]))
    for m in metadata:
        if isinstance(m, Ge):
            lo = m.ge
        elif isinstance(m, Gt):
            lo, lo_op = m.gt, "("
        elif isinstance(m, Le):
            hi = m.le
        elif isinstance(m, Lt):
            hi, hi_op = m.lt, ")"
    return lo, hi, lo_op, hi_op


def _fmt(value: Any) -> str:
    if isinstance(value, (dict, list)):
        try:
            text = yaml.safe_dump(value, default_flow_style=True, width=1 << 30).strip()
        except yaml.YAMLError:
            text = repr(value)
    else:
        text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _message(err: Dict[str, Any]) -> Tuple[Tuple, str]:
    """One operator-readable message for one pydantic error: (YAML path, text)."""
    loc = tuple(p for p in err["loc"] if not (isinstance(p, str) and p.startswith("function-after")))
    kind = err["type"]
    value = err.get("input")
    ctx = err.get("ctx", {})
    if kind == "extra_forbidden":
        parent_info, owner = _field_for(loc[:-1]) if len(loc) > 1 else (None, Config)
        model = parent_info.annotation if parent_info is not None else owner
        known = []
        if isinstance(model, type) and issubclass(model, BaseModel):
            known = [f.alias or n for n, f in model.model_fields.items()]
        guess = difflib.get_close_matches(str(loc[-1]), known, n=1, cutoff=0.6)
        hint = " (did you mean %r?)" % guess[0] if guess else " (allowed: %s)" % ", ".join(known) if known else ""
        return loc, "unknown key%s" % hint
    info, owner = _field_for(loc)
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        item = owner is None and bool(loc) and isinstance(loc[-1], int)
        lo, hi, lo_op, hi_op = _bounds(info, item) if info is not None else (None, None, "[", "]")
        if lo is not None and hi is not None:
            return loc, "%s is not in %s%s, %s%s" % (_fmt(value), lo_op, lo, hi, hi_op)
        limit = next(iter(ctx.values())) if ctx else "?"
        rel = {"greater_than": "> ", "greater_than_equal": ">= ", "less_than": "< ", "less_than_equal": "<= "}[kind]
        return loc, "%s must be %s%s" % (_fmt(value), rel, limit)
    if kind == "finite_number":
        return loc, "%s is not a finite number" % _fmt(value)
    if kind == "literal_error":
        return loc, "%s is not one of %s" % (_fmt(value), ctx.get("expected", ""))
    if kind == "missing":
        return loc, "is required"
    if kind in ("int_type", "int_parsing", "int_from_float", "int_parsing_size"):
        return loc, "%s is not a whole number" % _fmt(value)
    if kind in ("float_type", "float_parsing"):
        return loc, "%s is not a number" % _fmt(value)
    if kind in ("bool_type", "bool_parsing"):
        return loc, "%s is not true or false" % _fmt(value)
    if kind in ("string_type",):
        return loc, "%s is not text" % _fmt(value)
    if kind in ("string_too_short", "string_too_long"):
        return loc, "%s: %s" % (_fmt(value), err["msg"].lower())
    if kind in ("model_type", "dict_type", "model_attributes_type"):
        return loc, "%s should be a section of keys (a mapping)" % _fmt(value)
    if kind in ("tuple_type", "list_type", "too_short", "too_long"):
        return loc, "%s: %s" % (_fmt(value), err["msg"].lower())
    if kind == "value_error":
        return loc, str(ctx.get("error", err["msg"]))
    return loc, "%s: %s" % (_fmt(value), err["msg"])


def _dotted(loc: Tuple) -> str:
    out = ""
    for p in loc:
        out += "[%d]" % p if isinstance(p, int) and not isinstance(p, bool) else ("." if out else "") + str(p)
    return out or "(top level)"


def _where(source: str, lines: Dict[Tuple, int], loc: Tuple) -> str:
    line = next((lines[loc[:i]] for i in range(len(loc), 0, -1) if loc[:i] in lines), None)
    return "%s:%d" % (source, line) if line else source


def problem_line(source: str, lines: Dict[Tuple, int], loc: Tuple, message: str) -> str:
    """``FILE:LINE: dotted.key: message`` on one line."""
    return _one_line("%s: %s: %s" % (_where(source, lines, loc), _dotted(loc), message))


def _merged(defaults: Any, data: Any) -> Any:
    """``data`` laid over ``defaults``, section by section: a file that sets one key of a section
    keeps the section's other defaults. (Validating the file alone would build a partial section
    from its class defaults: the local stage's appearance would fall back to the global T0 and
    input size.)"""
    if not (isinstance(defaults, dict) and isinstance(data, dict)):
        return data
    out = dict(defaults)
    for key, value in data.items():
        out[key] = _merged(defaults.get(key) if isinstance(key, str) else None, value)
    return out


_DEFAULTS = Config().model_dump(by_alias=True)


def parse_config(data: Any, source: str = "<config>", lines: Optional[Dict[Tuple, int]] = None) -> Config:
    """Validate already-parsed YAML data; raise ConfigError with one line per problem."""
    if data is None:
        raise ConfigError(["%s: holds no settings: expected sections such as capture:, detector:, mavlink:" % source])
    if not isinstance(data, dict):
        raise ConfigError(["%s: the file must hold a mapping of sections (capture, detector, ...), got %s"
                           % (source, type(data).__name__)])
    try:
        return Config.model_validate(_merged(_DEFAULTS, data))
    except ValidationError as exc:
        problems = []
        for err in exc.errors():
            loc, msg = _message(err)
            problems.append(problem_line(source, lines or {}, loc, msg))
        raise ConfigError(problems) from None
    except RecursionError:  # a recursive structure handed in by a caller (files cannot hold one)
        raise ConfigError(["%s: nested too deeply" % source]) from None


def load_config(path: Optional[str] = None) -> Config:
    """Read and validate a YAML file; None gives the built-in defaults (= configs/default.yaml).

    The values only: ``payload.config.checks.load_run_config`` also checks the files and
    folders the config names, as ``run`` needs them."""
    if path is None:
        return Config()
    data, lines = read_yaml(path)
    return parse_config(data, source=path, lines=lines)


def config_with(base: Config, **overrides: Any) -> Config:
    """A copy of ``base`` with dotted-key overrides, validated: config_with(c, **{"detector.global.appearance.enabled": False})."""
    data = base.model_dump(by_alias=True)
    for dotted, value in overrides.items():
        node = data
        parts = dotted.split(".")
        for p in parts[:-1]:
            node = node[p]
        node[parts[-1]] = value
    return parse_config(data, source="<override>")
