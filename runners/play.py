"""`python -m runners.play` in a checkout: the same as `python -m rwalk.runners.play`."""

from rwalk.runners.play import main

if __name__ == "__main__":
    main()
