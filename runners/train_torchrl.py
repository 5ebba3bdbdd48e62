"""Checkout shim: `python -m runners.train_torchrl` runs `rwalk.runners.train_torchrl`."""

from rwalk.runners.train_torchrl import main

if __name__ == "__main__":
    main()
