"""The shipped configuration files, one per robot (``cheope.toml``, ``uru.toml``, ``nspu.toml``)."""

from pathlib import Path

CONFIG_DIR = Path(__file__).parent
