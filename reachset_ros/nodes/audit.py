"""Privileged operations (issue 17.4): who asked to reset a safe stop or to change the gains, and why.

A reset of the monitor's safe stop and a change of the controller's or observer's gains are
the two ways to move an arm the monitor stopped. Each request is logged, granted or refused,
as one ``PRIVILEGED`` line: the operation, the caller the request names (``ResetStop.caller``;
a ``std_srvs/Trigger`` or a parameter request names none), the reason it gives, the outcome,
and the nodes that have a client of the service in the ROS graph (what DDS discovery says;
without DDS-Security a client can name any node, so this is a record, not an
authentication: docs/reliability.md, "Privileged operations").
"""
from __future__ import annotations

__all__ = ["service_clients", "log_privileged"]


def service_clients(node, services):
    """Nodes (``/ns/name``) other than ``node`` with a client of any of ``services`` (full names)."""
    want = set(services)
    out = set()
    try:
        names = node.get_node_names_and_namespaces()
    except Exception:             # a graph query must never fail the operation it records
        return ["(graph not available)"]
    for name, ns in names:
        if name == node.get_name() and ns == node.get_namespace():
            continue
        try:
            clients = node.get_client_names_and_types_by_node(name, ns)
        except Exception:
            continue
        if any(c in want for c, _ in clients):
            out.add(ns.rstrip("/") + "/" + name)
    return sorted(out)


def log_privileged(node, operation, caller, reason, outcome, services):
    """Log one ``PRIVILEGED`` line (warning level) and return it."""
    clients = service_clients(node, services)
    line = (f"PRIVILEGED {operation}: caller {caller or 'not named (the request carries no caller)'}; "
            f"reason {reason.strip()!r}" if reason and reason.strip() else
            f"PRIVILEGED {operation}: caller {caller or 'not named (the request carries no caller)'}; no reason given")
    line += f"; {outcome}; clients of {', '.join(services)} in the graph: {', '.join(clients) or 'none seen'}"
    node.get_logger().warning(line)
    return line
