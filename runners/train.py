"""`python -m runners.train` in a checkout: the same as `python -m rwalk.runners.train`."""

from rwalk.runners.train import main

if __name__ == "__main__":
    main()
