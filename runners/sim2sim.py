"""Checkout shim: `python -m runners.sim2sim` runs `rwalk.runners.sim2sim`."""

from rwalk.runners.sim2sim import main

if __name__ == "__main__":
    main()
