"""Checkout shim: `python -m runners.bench` runs `rwalk.runners.bench`."""

from rwalk.runners.bench import main

if __name__ == "__main__":
    main()
