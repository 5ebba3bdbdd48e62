"""Checkout shim: `python -m runners.robustness` runs `rwalk.runners.robustness`."""

from rwalk.runners.robustness import main

if __name__ == "__main__":
    main()
