"""vice-raq: the web server, the store it shares with the learner, and the `raq` command."""
