"""The web server: the REST API and the HTML pages (app/routers/, one router per resource), the request guard, env
previews and camera views, exports, the demo and the oracle client. The store it shares with the learner lives in
contract/store/, the `raq` command in cli/."""
