"""`python -m runners.train_torchrl` in a checkout: the same as `python -m rwalk.runners.train_torchrl`."""

from rwalk.runners.train_torchrl import main

if __name__ == "__main__":
    main()
