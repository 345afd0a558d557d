"""Every test can import the measuring helpers that the core and Blender tests share (this folder)."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
