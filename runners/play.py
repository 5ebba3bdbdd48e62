"""Checkout shim: `python -m runners.play` runs `rwalk.runners.play`."""

from rwalk.runners.play import main

if __name__ == "__main__":
    main()
