"""`python -m runners.plot_training` in a checkout: the same as `python -m rwalk.runners.plot_training`."""

from rwalk.runners.plot_training import main

if __name__ == "__main__":
    main()
