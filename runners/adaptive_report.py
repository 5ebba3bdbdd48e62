"""Checkout shim: `python -m runners.adaptive_report` runs `rwalk.runners.adaptive_report`."""

from rwalk.runners.adaptive_report import main

if __name__ == "__main__":
    main()
