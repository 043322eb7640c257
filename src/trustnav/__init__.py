"""trustnav: trust-aware safe navigation (Ejaz and Inoue), offline on a CPU."""

__version__ = "0.1.0"
