"""Checkout shim: `python -m runners.base_gait_report` runs `rwalk.runners.base_gait_report`."""

from rwalk.runners.base_gait_report import main

if __name__ == "__main__":
    main()
