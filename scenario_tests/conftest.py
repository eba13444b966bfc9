"""The demo registers the example custom use case (examples/custom_usecase) the
way a team registers its own: by importing it from a conftest.py."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples" / "custom_usecase"))
import speed_limit  # noqa: E402,F401
