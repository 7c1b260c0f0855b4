"""rekon's Python client: the bus (rekon.bus), the map (rekon.mesh), session folders (rekon.session), the pieces of
a frontend (rekon.frontend) and bags in (rekon.bag). It mirrors rekon's C++ concepts; numpy in and out.

The LCM types (rekon_msgs) are generated from messages/*.lcm by the build (`lcm-gen -p`, target rekon_python_msgs)
into BUILD/python; rekon.msgs() finds them (REKON_BUILD_DIR, else the checkout's build/).
"""

from __future__ import annotations

import importlib
import os
import sys
from pathlib import Path

SOURCE_DIR = Path(__file__).resolve().parents[2]


def build_dir() -> Path:
    return Path(os.environ.get("REKON_BUILD_DIR", SOURCE_DIR / "build"))


def msgs():
    """The generated rekon_msgs package; one line naming the fix when the build has not made it."""
    try:
        return importlib.import_module("rekon_msgs")
    except ImportError:
        generated = build_dir() / "python"
        if not (generated / "rekon_msgs" / "__init__.py").exists():
            raise ImportError(f"rekon_msgs (the Python LCM types) is not in {generated}: build it with "
                              f"tools/rekon setup (target rekon_python_msgs), or set REKON_BUILD_DIR") from None
        sys.path.insert(0, str(generated))
        return importlib.import_module("rekon_msgs")


def schema_version() -> int:
    """The schema_version this build's messages carry (kSchemaVersion of common/.../bus.hpp, written by the build)."""
    msgs()
    return importlib.import_module("rekon_schema").SCHEMA_VERSION
