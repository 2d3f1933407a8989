import sys
from pathlib import Path

# Tests import their helpers (tests.render) from the repository root.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
