"""Where the repository is, for tests that run its command line."""

import pathlib

REPO = pathlib.Path(__file__).resolve().parents[1]
