"""Checkout shim: `python -m runners.plot_training` runs `rwalk.runners.plot_training`."""

from rwalk.runners.plot_training import main

if __name__ == "__main__":
    main()
