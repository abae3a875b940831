"""Property tests of the config loader (issue 20): whatever the file holds - random bytes, random
text, random nested mappings with huge integers, NaN, infinities and odd keys, YAML aliases of any
width and depth - the only exception that leaves ``load_config``/``parse_config`` is ConfigError,
and each of its problems is one line."""

import math

import pytest
import yaml

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from payload.config import Config, flat_config, load_config, parse_config  # noqa: E402
from payload.errors import ConfigError  # noqa: E402

FUZZ = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                        HealthCheck.too_slow])

# the config's own key names, so that random mappings reach deep into the schema
KEY_PARTS = sorted({part for key in flat_config(Config()) for part in key.split(".")})
SECTIONS = ["capture", "camera", "detector", "mavlink", "outputs", "logging"]

scalars = st.one_of(
    st.none(), st.booleans(),
    st.integers(), st.integers(min_value=-(10 ** 90), max_value=10 ** 90), st.sampled_from([10 ** 400, -(2 ** 64)]),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -0.0]),
    st.text(max_size=20), st.sampled_from(KEY_PARTS + ["GAD", "LMD", "udpout:127.0.0.1:99999", "/dev/full"]),
)
keys = st.one_of(st.sampled_from(KEY_PARTS + SECTIONS + ["global"]), st.text(max_size=10), st.integers(), st.booleans())
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=6),
                                                        st.dictionaries(keys, inner, max_size=6)), max_leaves=40)
configs = st.dictionaries(st.sampled_from(SECTIONS), st.dictionaries(keys, values, max_size=8), max_size=6)


def _load(tmp_path, content):
    path = tmp_path / "fuzz.yaml"
    path.write_bytes(content)
    try:
        load_config(str(path))
    except ConfigError as exc:
        _one_line_each(exc)


def _one_line_each(exc):
    assert exc.problems
    for line in exc.problems:
        assert isinstance(line, str) and line and len(line.splitlines()) == 1, line


@FUZZ
@given(content=st.binary(max_size=2000))
def test_random_bytes(tmp_path, content):
    _load(tmp_path, content)


@FUZZ
@given(text=st.text(max_size=2000))
def test_random_text(tmp_path, text):
    _load(tmp_path, text.encode("utf-8", "surrogatepass"))


@FUZZ
@given(data=configs)
def test_random_mappings_as_yaml(tmp_path, data):
    _load(tmp_path, yaml.safe_dump(data, allow_unicode=True).encode("utf-8", "surrogatepass"))


@FUZZ
@given(data=st.one_of(configs, values))
def test_random_data_parsed(data):
    try:
        parse_config(data, source="<fuzz>")
    except ConfigError as exc:
        _one_line_each(exc)


@FUZZ
@given(width=st.integers(1, 15), depth=st.integers(1, 9), where=st.sampled_from(SECTIONS + ["x"]),
       inner=st.sampled_from(["[x, x]", "{a: 1}", "1.5", "*a0", "[*a0, *a0]"]))
def test_aliases_of_any_width_and_depth(tmp_path, width, depth, where, inner):
    lines = ["a0: &a0 %s" % (inner if inner != "*a0" and inner != "[*a0, *a0]" else "[1, 2]")]
    for i in range(1, depth + 1):
        lines.append("a%d: &a%d [%s]" % (i, i, ", ".join(["*a%d" % (i - 1)] * width)))
    lines.append("%s: *a%d" % (where, depth))
    if inner.startswith("[*a0"):
        lines[0] = "a0: &a0 [1, %s]" % inner  # an alias inside the anchor's own value: refused, not looped
    _load(tmp_path, ("\n".join(lines) + "\n").encode())


@FUZZ
@given(data=configs)
def test_shared_objects_dumped_as_aliases(tmp_path, data):
    # yaml.safe_dump writes an anchor and aliases for an object that appears more than once
    shared = {"shared": data, "again": data, "capture": {"retry": data.get("capture", {})}, "logging": data}
    _load(tmp_path, yaml.safe_dump(shared, allow_unicode=True).encode("utf-8", "surrogatepass"))
