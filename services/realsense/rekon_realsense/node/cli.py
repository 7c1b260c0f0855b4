"""The entry point build/bin/rekon-realsense runs: first the packages it needs,
each missing one named in one line with the fix, then main()."""
import importlib
import sys

NEEDED = [("lcm", "lcm"), ("numpy", "numpy"), ("yaml", "PyYAML"), ("PIL", "pillow"), ("pyrealsense2", "pyrealsense2")]


def main():
    missing = []
    for module, package in NEEDED:
        try:
            importlib.import_module(module)
        except ImportError:
            missing.append(package)
    if missing:
        named = ", ".join(p + (" (Intel's RealSense SDK)" if p == "pyrealsense2" else "") for p in missing)
        print(f"rekon-realsense: error: missing Python packages in {sys.prefix}: {named}; run tools/rekon deps (it "
              "installs python/requirements.txt from PyPI)", file=sys.stderr)
        return 1
    try:
        importlib.import_module("rekon_msgs")
        importlib.import_module("rekon_schema")
    except ImportError:
        print("rekon-realsense: error: the Python LCM types (build/python/rekon_msgs) are missing; build them: "
              "cmake --build build --target rekon_python_msgs", file=sys.stderr)
        return 1
    from .main import main as service_main
    return service_main(sys.argv[1:])


if __name__ == "__main__":
    sys.exit(main())
