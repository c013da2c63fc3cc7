"""Thin entry point: ``python train.py ...`` == ``tactilesnn train ...``."""

import sys

from tactilesnn.cli import main

if __name__ == "__main__":
    sys.exit(main(["train", *sys.argv[1:]]))
