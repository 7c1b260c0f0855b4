"""rekon's configuration as the C++ services read it (common/src/config.cpp):
config/default.yaml is the schema and the defaults; a --config file and each
--set key=value are laid over it; an unknown key, or a section given a value,
is an error naming the key."""
import os

import yaml

from .errors import Error

FIX = "see config/default.yaml for every key and its type"


def default_config_path():
    root = os.environ.get("REKON_SOURCE_DIR") or os.path.abspath(
        os.path.join(os.path.dirname(__file__), "..", "..", ".."))
    return os.path.join(root, "config", "default.yaml")


def _parse(text, source):
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        line = getattr(getattr(e, "problem_mark", None), "line", -1) + 1
        raise Error(f"{source}: invalid YAML at line {line}; fix the file") from None


def _overlay(base, over, prefix, source):
    if not isinstance(over, dict):
        raise Error(f"{source}: {prefix or 'top level'} must be a mapping; {FIX}")
    for name, value in over.items():
        key = f"{prefix}.{name}" if prefix else str(name)
        if name not in base:
            raise Error(f"{source}: unknown config key '{key}'; {FIX}")
        if isinstance(base[name], dict):
            _overlay(base[name], value, key, source)
        elif isinstance(value, dict):
            raise Error(f"{source}: config key '{key}' is a value, not a section; {FIX}")
        else:
            base[name] = value


class Config:
    def __init__(self, root):
        self.root = root

    @staticmethod
    def load(file="", sets=(), defaults_path=None):
        path = defaults_path or default_config_path()
        try:
            with open(path, encoding="utf-8") as f:
                root = _parse(f.read(), path)
        except OSError:
            raise Error(f"{path}: cannot read rekon's default configuration; set REKON_SOURCE_DIR to the rekon "
                        "source tree") from None
        config = Config(root)
        if file:
            try:
                with open(file, encoding="utf-8") as f:
                    text = f.read()
            except OSError:
                raise Error(f"{file}: cannot read config file; check the --config path") from None
            over = _parse(text, file)
            if over is not None:
                _overlay(config.root, over, "", file)
        for s in sets:
            key, eq, value = s.partition("=")
            if not eq or not key:
                raise Error(f"--set {s}: expected key=value, for example --set realsense.emitter=off")
            config.set(key, value)
        return config

    def _node(self, key):
        n = self.root
        for part in key.split("."):
            if not isinstance(n, dict) or part not in n:
                raise Error(f"config key '{key}' does not exist; {FIX}")
            n = n[part]
        return n

    def set(self, key, value):
        parts = key.split(".")
        n = self.root
        for part in parts[:-1]:
            if not isinstance(n, dict) or part not in n:
                raise Error(f"--set {key}: unknown config key; {FIX}")
            n = n[part]
        if not isinstance(n, dict) or parts[-1] not in n:
            raise Error(f"--set {key}: unknown config key; {FIX}")
        if isinstance(n[parts[-1]], dict):
            raise Error(f"--set {key}: is a section, not a value; {FIX}")
        n[parts[-1]] = _parse(value, f"--set {key}") if isinstance(value, str) else value

    def get_string(self, key):
        v = self._node(key)
        if v is None:
            return ""
        if isinstance(v, (dict, list)):
            raise Error(f"config key '{key}' must be a string; {FIX}")
        if isinstance(v, bool):
            return "true" if v else "false"
        return str(v)

    def get_double(self, key):
        v = self._node(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise Error(f"config key '{key}' must be a number; {FIX}")
        return float(v)

    def get_int(self, key):
        v = self._node(key)
        if isinstance(v, bool) or not isinstance(v, int):
            raise Error(f"config key '{key}' must be an integer; {FIX}")
        return v

    def get_bool(self, key):
        v = self._node(key)
        if not isinstance(v, bool):
            raise Error(f"config key '{key}' must be true or false; {FIX}")
        return v

    def get_string_list(self, key):
        v = self._node(key)
        if v is None:
            return []
        if not isinstance(v, list) or any(isinstance(x, (dict, list)) for x in v):
            raise Error(f"config key '{key}' must be a list of strings; {FIX}")
        return [str(x) for x in v]
