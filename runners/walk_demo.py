"""`python -m runners.walk_demo` in a checkout: the same as `python -m rwalk.runners.walk_demo`."""

from rwalk.runners.walk_demo import main

if __name__ == "__main__":
    main()
