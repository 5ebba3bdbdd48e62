"""Checkout shim: `python -m runners.train` runs `rwalk.runners.train`."""

from rwalk.runners.train import main

if __name__ == "__main__":
    main()
