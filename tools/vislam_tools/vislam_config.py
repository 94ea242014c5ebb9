"""The configuration vislam-run would use, read from its own --print-config (one definition)."""

import configparser
import subprocess


def read_config(vislam_run, preset=None, config_file=None, max_landmarks=None):
    """Every plain key of vislam-run's effective configuration (the calibration left out), by key
    name: booleans for true/false, the mode as text, numbers as floats. A vislam-run that refuses
    the configuration raises subprocess.CalledProcessError (its stderr attached)."""
    cmd = [str(vislam_run), "--print-config"]
    if preset:
        cmd += ["--preset", preset]
    if config_file:
        cmd += ["--config", str(config_file)]
    if max_landmarks:
        cmd += ["--max-landmarks", str(max_landmarks)]
    text = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    ini = configparser.ConfigParser(inline_comment_prefixes=("#", ";"))
    ini.read_string(text)
    cfg = {}
    for section in ini.sections():
        if section == "calibration":
            continue
        for key, value in ini[section].items():
            if value in ("true", "false"):
                cfg[key] = value == "true"
            elif key == "mode":
                cfg[key] = value
            else:
                cfg[key] = float(value)
    return cfg
