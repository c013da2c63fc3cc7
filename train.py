"""Thin entry point: ``python train.py ...`` is the ``tactilesnn`` command line
(``python train.py train --data f.npz``, ``python train.py evaluate RUN``...); with no command,
or options only, it trains (``python train.py --epochs 5`` == ``tactilesnn train --epochs 5``)."""

import sys

from tactilesnn.cli import COMMANDS, main

if __name__ == "__main__":
    argv = sys.argv[1:]
    is_command = bool(argv) and (argv[0] in COMMANDS or argv[0] in ("-h", "--help", "--version"))
    sys.exit(main(argv if is_command else ["train", *argv]))
