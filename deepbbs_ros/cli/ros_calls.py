"""``deepbbs-ros reset`` / ``relocalize`` / ``lifecycle`` / ``param``: calls to a running node's services, and the
waits for a service or a topic to appear that every command shares."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from deepbbs_ros.errors import NodeError


def node_name(name: str) -> str:
    return name if name.startswith("/") else "/" + name


def spin_until(node: Any, future: Any, timeout: float, what: str) -> Any:
    import rclpy

    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
    if not future.done():
        raise NodeError(f"{what}: no answer within {timeout} s")
    if future.exception() is not None:
        raise NodeError(f"{what}: {future.exception()}")
    return future.result()


def client(node: Any, srv_type: Any, name: str, timeout: float) -> Any:
    cli = node.create_client(srv_type, name)
    if not cli.wait_for_service(timeout_sec=min(timeout, 1.0)):
        waiting(f"service {name}", timeout)
        if not cli.wait_for_service(timeout_sec=max(timeout - 1.0, 0.0)):
            raise NodeError(f"service {name} not available within {timeout:g} s (is the node running, "
                            "same ROS_DOMAIN_ID?)")
    return cli


def waiting(what: str, timeout: float) -> None:
    print(f"waiting up to {timeout:g} s for {what} to appear (--timeout; a node takes seconds to start) ...",
          file=sys.stderr, flush=True)


def reset(node: Any, args: argparse.Namespace) -> int:
    from std_srvs.srv import Trigger

    name = node_name(args.node) + ("/relocalize" if args.command == "relocalize" else "/reset")
    res = spin_until(node, client(node, Trigger, name, args.timeout).call_async(Trigger.Request()),
                     args.timeout, name)
    print(f"{name}: {'ok' if res.success else 'failed'}: {res.message}")
    return 0 if res.success else 1


def lifecycle(node: Any, args: argparse.Namespace) -> int:
    """``lifecycle get NODE``: its state; ``lifecycle set NODE TRANSITION``: the transition by its label (as ros2
    lifecycle), then the state it reached; exit code 1 when the node refused or failed it (its log says why)."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState, GetState

    name = node_name(args.node)
    get = client(node, GetState, name + "/get_state", args.timeout)
    ok = True
    if args.action == "set":
        change = client(node, ChangeState, name + "/change_state", args.timeout)
        request = ChangeState.Request(transition=Transition(label=args.transition))
        ok = spin_until(node, change.call_async(request), args.timeout, f"{name} {args.transition}").success
    state = spin_until(node, get.call_async(GetState.Request()), args.timeout, name + "/get_state").current_state
    if args.action == "set":
        print(f"{name}: {args.transition} {'ok' if ok else 'failed (the node logs why)'}; now {state.label}")
    else:
        print(f"{name}: {state.label} [{state.id}]")
    return 0 if ok else 1


def param(node: Any, args: argparse.Namespace) -> int:
    from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
    from rclpy.parameter import Parameter, parameter_value_to_python

    target = node_name(args.node)
    if args.action == "list":
        res = spin_until(node, client(node, ListParameters, f"{target}/list_parameters", args.timeout)
                         .call_async(ListParameters.Request()), args.timeout, f"{target}/list_parameters")
        for name in sorted(res.result.names):
            print(name)
        return 0
    if args.action == "get":
        req = GetParameters.Request(names=[args.name])
        res = spin_until(node, client(node, GetParameters, f"{target}/get_parameters", args.timeout)
                         .call_async(req), args.timeout, f"{target}/get_parameters")
        if not res.values or res.values[0].type == 0:
            raise NodeError(f"{target}: parameter {args.name!r} is not set{_did_you_mean(node, target, args)}")
        print(_format_value(parameter_value_to_python(res.values[0])))
        return 0
    import yaml

    try:
        value = yaml.safe_load(args.value)
    except yaml.YAMLError:
        value = args.value
    if value is None:
        value = args.value
    try:
        msg = Parameter(args.name, value=value).to_parameter_msg()
    except (TypeError, ValueError) as err:
        raise NodeError(f"{args.name}: cannot send {args.value!r} as a parameter value ({err})") from err
    res = spin_until(node, client(node, SetParameters, f"{target}/set_parameters", args.timeout)
                     .call_async(SetParameters.Request(parameters=[msg])), args.timeout, f"{target}/set_parameters")
    result = res.results[0]
    if not result.successful:
        raise NodeError(f"{target}: setting {args.name} refused: {result.reason or 'no reason given'}")
    print(f"{target}: {args.name} = {_format_value(value)}")
    return 0


def _did_you_mean(node: Any, target: str, args: argparse.Namespace) -> str:
    """``; did you mean node.mode?`` from the node's own parameters (the config schema it declared), with the
    did-you-mean of the node's -p check and of config files (:func:`deepbbs_ros.config.did_you_mean`); a config
    key the node does not declare says so."""
    from rcl_interfaces.srv import ListParameters

    from deepbbs_ros.config import Config, did_you_mean

    try:
        res = spin_until(node, client(node, ListParameters, f"{target}/list_parameters", args.timeout)
                         .call_async(ListParameters.Request()), args.timeout, f"{target}/list_parameters")
    except NodeError:
        return ""
    names = list(res.result.names)
    if args.name in Config().to_flat():
        return " (a config key this node does not declare: see deepbbs-ros param list)"
    return did_you_mean(args.name, names)


def _format_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)) or type(value).__name__ == "ndarray":
        return "[" + ", ".join(_format_value(v) for v in list(value)) + "]"
    return str(value)
