"""Entry points: the command line, its commands and the batch runner."""
