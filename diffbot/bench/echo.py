"""The bus suite's echo process: ``python -m diffbot.bench.echo --echo ENDPOINT``.

Run as its own module (not ``roundtrip``, which the package has already imported by the
time ``-m`` would run it again)."""
import sys

from diffbot.bench.roundtrip import echo_main

if __name__ == "__main__":
    if sys.argv[1:2] != ["--echo"] or len(sys.argv) != 3:
        sys.exit("usage: python -m diffbot.bench.echo --echo ENDPOINT")
    sys.exit(echo_main(sys.argv[2]))
