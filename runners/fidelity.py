"""Checkout shim: `python -m runners.fidelity` runs `rwalk.runners.fidelity`."""

from rwalk.runners.fidelity import main

if __name__ == "__main__":
    main()
