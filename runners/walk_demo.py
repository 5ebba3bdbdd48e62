"""Checkout shim: `python -m runners.walk_demo` runs `rwalk.runners.walk_demo`."""

from rwalk.runners.walk_demo import main

if __name__ == "__main__":
    main()
