"""One router per resource: runs, goal sets, queries, metrics, events, health, and the HTML pages."""
