"""The study: its sensor experiments, their bus runs and plots, and `diffbot figures` (the
twelve figures and their report), run through :mod:`diffbot.runner`."""
