"""The node's topic names and the check of a command line's remap rules against them (rclpy ignores a remap whose
name is none of the node's topics; the node says so, naming its inputs)."""

from __future__ import annotations

from typing import Any

PAIR_INPUTS = ("source_cloud", "target_cloud")
ODOM_INPUT = "cloud"
KISS_ICP_INPUT = "pointcloud_topic"  # KISS-ICP's input name: taken as the odometry input when remapped
#: the node's other topics and services (remapping them is legitimate; parameter services are under ``~/``)
NODE_TOPICS = ("~/pose", "~/transform", "~/odometry", "~/aligned_cloud", "~/reset", "~/relocalize", "/tf",
               "~/pose_with_covariance", "/initialpose",
               "/tf_static", "/diagnostics", "/clock", "/rosout", "/parameter_events")


def remap_rules(argv: Any) -> list[tuple[str, str, str]]:
    """The topic remap rules of ``argv``'s ``--ros-args`` sections: ``(node, from, to)`` for each ``-r`` /
    ``--remap [node:]from:=to`` (node '' when the rule is for every node); ``__node``, ``__ns`` and other
    special names are left out."""
    rules, in_ros, it = [], False, iter(argv or [])
    for a in it:
        if a == "--ros-args":
            in_ros = True
        elif in_ros and a == "--":
            in_ros = False
        elif in_ros and a in ("-r", "--remap"):
            rule = next(it, "")
            lhs, sep, to = rule.partition(":=")
            node, _, name = lhs.rpartition(":")
            if sep and name and not name.startswith("__"):
                rules.append((node, name, to))
    return rules


def unmatched_remaps(rules: Any, mode: str, node_name: str, namespace: str) -> list[str]:
    """Warnings for the remap rules (:func:`remap_rules`) whose name is none of the node's topics (the inputs of
    ``mode``: ``source_cloud``, ``target_cloud`` or ``cloud`` / ``pointcloud_topic``; :data:`NODE_TOPICS`;
    anything under ``~/``): rclpy ignores them, so a misspelt or other-mode input would leave the node waiting
    on its default topic with no word. Each warning names the node's inputs."""
    import difflib

    from rclpy.expand_topic_name import expand_topic_name

    def expand(name: str) -> str | None:
        try:
            return expand_topic_name(name, node_name, namespace)
        except Exception:  # noqa: BLE001 - an invalid name: rclpy reports it itself
            return None

    inputs = PAIR_INPUTS if mode == "pair" else (ODOM_INPUT, KISS_ICP_INPUT)
    names = ", ".join(inputs) if mode == "pair" else f"{ODOM_INPUT} (or {KISS_ICP_INPUT}, KISS-ICP's name)"
    private = expand("~") or ""
    known = {expand(n): n for n in (*inputs, *NODE_TOPICS)}
    other_mode = {ODOM_INPUT: "odometry", KISS_ICP_INPUT: "odometry", **{n: "pair" for n in PAIR_INPUTS}}
    out = []
    for node, name, to in rules:
        if node and node != node_name:
            continue  # another node's rule
        full = expand(name)
        if full is None or full in known or full.startswith(private + "/") or full == expand(to):
            continue  # one of the node's names, or a rule that changes nothing (the launch file's defaults)
        leaf = name.rpartition("/")[2]
        hint = ""
        if leaf in other_mode and other_mode[leaf] != mode:
            what = " (KISS-ICP's input name)" if leaf == KISS_ICP_INPUT else ""
            hint = f"; {leaf}{what} is an input of node.mode {other_mode[leaf]} (-p node.mode:={other_mode[leaf]})"
        else:
            near = difflib.get_close_matches(leaf, list(inputs), n=1, cutoff=0.6)
            hint = f"; did you mean {near[0]}:={to}?" if near else ""
        out.append(f"remap {name}:={to} matches no topic of this node and is ignored: its inputs are "
                   f"{names} (node.mode={mode}){hint}")
    return out
