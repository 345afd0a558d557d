"""Robustness tests reuse the core tests' small geometry helpers (tests/core/shapes.py)."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[1] / "core"))
