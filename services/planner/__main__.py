import sys

from .main import run

if __name__ == "__main__":  # the planning process (multiprocessing spawn) imports this module too
    sys.exit(run())
