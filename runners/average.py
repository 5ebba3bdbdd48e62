"""Checkout shim: `python -m runners.average` runs `rwalk.runners.average`."""

from rwalk.runners.average import main

if __name__ == "__main__":
    main()
