"""One router per resource: runs, their exports, metrics, events, reward health and robot, comparison, goal sets and
cameras, queries, envs, the config reference, health, the API docs and the HTML pages. A router imports app.deps,
app.schemas and shared helpers (app.views, app.previews, …), never another router."""
