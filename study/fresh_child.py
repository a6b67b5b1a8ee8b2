"""The child process of :mod:`study.fresh`: it imports the code on this machine's disk now and runs the cells the
worker hands it over two pipes (``python -m study.fresh_child REQUEST_FD REPLY_FD``).

Apart from :mod:`study.fresh` (the worker's side), so that :mod:`study.cells` can start a child without the two
importing each other.
"""

from __future__ import annotations

import os
import sys
from typing import IO

from study.cells import run_cell
from study.fresh import _receive, _send


def serve(requests: IO[bytes], replies: IO[bytes]) -> int:
    while True:
        try:
            cell, variants, expected = _receive(requests)
        except EOFError:  # the worker closed the pipe (or died): done
            return 0
        _send(replies, run_cell(cell, variants, expected, fresh=False))  # fresh=False: never a child of a child


if __name__ == "__main__":
    sys.exit(serve(os.fdopen(int(sys.argv[1]), "rb"), os.fdopen(int(sys.argv[2]), "wb")))
