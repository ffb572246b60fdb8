"""One router per resource: runs, robots, goal sets, queries, metrics, events, health, and the HTML pages."""
