"""`python -m runners.bench` in a checkout: the same as `python -m rwalk.runners.bench`."""

from rwalk.runners.bench import main

if __name__ == "__main__":
    main()
