"""Every runtime module imports on the interpreter running the tests.

Under `make test38` that is Python 3.8 with JetPack-like NumPy/OpenCV/pydantic: annotations such as
``list[int]`` or ``X | None`` in a signature, or a 3.9+ stdlib import, fail here at import time even in
modules no other test reaches. Optional extras (PyGObject, torch) are absent there, so this also checks
that the runtime imports them only where they are used.
"""

import importlib
import pkgutil

import pytest

import payload


def _runtime_modules():
    # __main__ runs the CLI when imported.
    return sorted(
        info.name for info in pkgutil.walk_packages(payload.__path__, "payload.") if not info.name.endswith(".__main__")
    )


@pytest.mark.parametrize("name", _runtime_modules())
def test_module_imports(name):
    importlib.import_module(name)
