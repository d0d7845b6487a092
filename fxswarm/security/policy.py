"""Who may say and hear what: Zenoh ``access_control`` for a scenario, by certificate common name.

Default deny. Each process's rights are its row of the roles table
(docs/design.md "The system"), taken from the nodes themselves where they exist, so the
rules cannot drift from what the code subscribes to:

========== ======================================= =============================================
name       may put                                 may hear (subscribe, and be sent)
========== ======================================= =============================================
world      ``world/**``; answers ``world/record``  ``WorldNode.subscriptions()`` (every command)
leader     ``leader/state``                        ``LeaderNode.subscriptions()`` (the first robot's
                                                   sensing, for the tick)
agent-<i>  ``agent/<i>/**``                        ``AgentNode(i).subscriptions()``: its sensing,
                                                   its neighbours' commands (their estimates ride
                                                   on them), the leader if pinned
logger     nothing                                 everything of the swarm
observer   nothing                                 ``world/state`` (progress line, health, ``fxswarm
                                                   attach``), the router's answer to ``scenario``
                                                   and the world's to ``world/record``
router     nothing                                 nothing
========== ======================================= =============================================

Liveliness: each process may declare only its own token (``alive/<role>/<id>``;
the world also ``run/over``; an observer any ``alive/observer/<id>``, which a world started
with ``--wait-for observer/<id>`` waits for); every process may watch and query tokens (who is
up is not secret inside the swarm, and the health check needs it).
Queries: only the observer may ask (``scenario``, ``world/record``), and only the world may
answer ``world/record`` (declare the queryable, be sent the query, reply): a robot can neither
read the run's record nor forge it. Subscriber declarations travel to every process (``declare_subscriber``
egress): a publisher sends only where someone listens.

A put must pass twice: ingress at the sender's link (may it say this?) and
egress at each receiver's (may it hear this?). Refusals are silent to the
sender; the router logs them (docs/security.md "Where refusals show").
"""

from __future__ import annotations

from fxswarm.agents.node import AgentNode
from fxswarm.core import bus as topics
from fxswarm.core.scenario import Scenario
from fxswarm.leader.node import LeaderNode
from fxswarm.runtime.tls import ALL_MESSAGES
from fxswarm.world.node import WorldNode

#: Processes every scenario has, besides one ``agent-<i>`` per robot.
FIXED_NAMES = ("router", "world", "leader", "logger", "observer")


def process_names(scenario: Scenario) -> list[str]:
    """Every certificate a scenario needs: the fixed roles, then ``agent-<i>`` per robot."""
    return [*FIXED_NAMES, *(f"agent-{r.id}" for r in scenario.robots)]


def rights(scenario: Scenario) -> dict[str, dict[str, list[str]]]:
    """``{name: {"put": topics, "hear": patterns, "tokens": topics, "ask": topics, "answer": topics}}``,
    topics relative to the swarm; ``ask``: keys it may query (and be sent the replies of); ``answer``:
    keys it may serve (declare a queryable, be sent the queries, reply)."""
    out: dict[str, dict[str, list[str]]] = {
        "router": {"put": [], "hear": [], "tokens": []},
        # The real-time world also hears the leader's states, to wait for a lagging leader.
        "world": {"put": ["world/**"],
                  "hear": [*WorldNode(scenario, record=False).subscriptions(), topics.LEADER_STATE],
                  "tokens": [topics.alive_topic("world", 0), topics.RUN_OVER], "answer": [topics.WORLD_RECORD]},
        "leader": {"put": [topics.LEADER_STATE], "hear": [*LeaderNode(scenario).subscriptions(), topics.RESYNC],
                   "tokens": [topics.alive_topic("leader", 0)]},
        "logger": {"put": [], "hear": ["**"], "tokens": [topics.alive_topic("logger", 0)]},
        # `fxswarm attach` is an observer: it reads the world's states, asks the router for the
        # scenario and announces itself, so that a world may wait for it (docs/security.md).
        "observer": {"put": [], "hear": [topics.WORLD_STATE], "tokens": [topics.alive_topic("observer", "*")],
                     "ask": [topics.SCENARIO, topics.WORLD_RECORD]},
    }
    for r in scenario.robots:
        out[f"agent-{r.id}"] = {"put": [f"agent/{r.id}/**"],
                                "hear": [*AgentNode(scenario, r.id).subscriptions(), topics.RESYNC],
                                "tokens": [topics.alive_topic("agent", r.id)]}
    return out


def access_control(scenario: Scenario, swarm: str = "*") -> dict:
    """The router's ``access_control`` configuration section (a JSON-able dict).

    ``swarm``: the swarm name, or ``*`` (any single-chunk name: the keys of one
    `fxswarm keys` run serve whatever swarm name a run picks).
    """
    root = topics.prefix(swarm)

    def keys(rel: list[str]) -> list[str]:
        return [f"{root}/{k}" for k in rel]

    rules = [
        # Everyone: watch and query liveliness, learn of tokens, hear where subscribers are.
        {"id": "liveliness", "messages": ["declare_liveliness_subscriber", "liveliness_query"],
         "flows": ["ingress"], "permission": "allow", "key_exprs": keys(["alive/**", topics.RUN_OVER])},
        {"id": "liveliness-news", "messages": ["liveliness_token", "reply", "declare_liveliness_subscriber"],
         "flows": ["egress"], "permission": "allow", "key_exprs": keys(["alive/**", topics.RUN_OVER])},
        {"id": "interest", "messages": ["declare_subscriber"], "flows": ["egress"], "permission": "allow",
         "key_exprs": keys(["**"])},
    ]
    # Routers meshed with each other (several routers, docs/deploy.md) forward everything their
    # clients may say: each router checks its own clients, so another router (a `router`
    # certificate) is trusted with all, as every process trusts it (fxswarm.runtime.tls.session_rules).
    rules.append({"id": "routers-forward", "messages": list(ALL_MESSAGES), "flows": ["ingress", "egress"],
                  "permission": "allow", "key_exprs": keys(["**"])})
    subjects = []
    policies = [{"id": "everyone", "rules": ["liveliness", "liveliness-news", "interest"], "subjects": []},
                {"id": "routers", "rules": ["routers-forward"], "subjects": ["s-router"]}]
    for name, r in rights(scenario).items():
        subject = f"s-{name}"
        subjects.append({"id": subject, "cert_common_names": [name]})
        policies[0]["subjects"].append(subject)
        mine = []
        if r["put"]:
            rules.append({"id": f"{name}-put", "messages": ["put"], "flows": ["ingress"], "permission": "allow",
                          "key_exprs": keys(r["put"])})
            mine.append(f"{name}-put")
        if r["hear"]:
            rules.append({"id": f"{name}-subscribe", "messages": ["declare_subscriber"], "flows": ["ingress"],
                          "permission": "allow", "key_exprs": keys(r["hear"])})
            rules.append({"id": f"{name}-hear", "messages": ["put"], "flows": ["egress"], "permission": "allow",
                          "key_exprs": keys(r["hear"])})
            mine += [f"{name}-subscribe", f"{name}-hear"]
        if r["tokens"]:
            rules.append({"id": f"{name}-token", "messages": ["liveliness_token"], "flows": ["ingress"],
                          "permission": "allow", "key_exprs": keys(r["tokens"])})
            mine.append(f"{name}-token")
        if r.get("ask"):
            rules.append({"id": f"{name}-ask", "messages": ["query"], "flows": ["ingress"], "permission": "allow",
                          "key_exprs": keys(r["ask"])})
            rules.append({"id": f"{name}-answer", "messages": ["reply"], "flows": ["egress"],
                          "permission": "allow", "key_exprs": keys(r["ask"])})
            mine += [f"{name}-ask", f"{name}-answer"]
        if r.get("answer"):
            rules.append({"id": f"{name}-serve", "messages": ["declare_queryable", "reply"], "flows": ["ingress"],
                          "permission": "allow", "key_exprs": keys(r["answer"])})
            rules.append({"id": f"{name}-asked", "messages": ["query"], "flows": ["egress"],
                          "permission": "allow", "key_exprs": keys(r["answer"])})
            mine += [f"{name}-serve", f"{name}-asked"]
        if mine:
            policies.append({"id": f"p-{name}", "rules": mine, "subjects": [subject]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}
