"""`python -m runners.base_gait_report` in a checkout: the same as `python -m rwalk.runners.base_gait_report`."""

from rwalk.runners.base_gait_report import main

if __name__ == "__main__":
    main()
