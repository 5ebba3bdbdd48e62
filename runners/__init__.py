"""``python -m runners.<name>`` in a checkout: shims over ``rwalk.runners``.

The runners ship inside the package (``rwalk.runners``, console scripts
``rwalk-train``, ``rwalk-play``, ...); this folder only keeps the checkout's
short commands working and is not installed.
"""
