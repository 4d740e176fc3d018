"""Validate a parameter request in ``on_set``, apply it in ``post_set``.

The split of ros2/demos ``demo_nodes_py/parameters/set_parameters_callback.py``: rclpy calls a
node's ``on_set`` callbacks before it stores a request's values (they may refuse it, with a
reason, and must leave the node as it was) and its ``post_set`` callbacks after it stored
them (they cannot refuse). A node validates the request in ``on_set`` and, when it accepts,
holds what it validated (a certified gain pair, a loaded model) in a :class:`StagedRequest`;
its ``post_set`` takes it back and applies it, once. rclpy passes both callbacks the same
list of parameters, which is how the request is recognised.
"""
from array import array

from ..errors import ReachsetError


class StagedRequest:
    """The parameter request a node's ``on_set`` callback accepted, until its ``post_set``."""

    def __init__(self):
        self._request = None

    def hold(self, params, staged=None):
        """Keep what ``on_set`` validated for the request ``params`` (replaces any older one)."""
        self._request = (params, staged)

    def take(self, params):
        """What ``on_set`` validated for ``params`` (the same list rclpy gave it); forgotten
        afterwards, so it is applied once. ReachsetError when ``on_set`` accepted no such
        request (rclpy calls ``post_set`` only after every ``on_set`` accepted it)."""
        request, self._request = self._request, None
        if request is None or request[0] is not params:
            raise ReachsetError("post_set parameters callback without a request accepted by on_set")
        return request[1]


def add_parameter_callbacks(node, *, on_set, post_set, take_repeats=False):
    """Register ``on_set`` (validate) and ``post_set`` (apply) on ``node``.

    With ``take_repeats``, a request that repeats the running values (:func:`repeats_current`)
    is accepted as it is: neither callback sees it (no gate, no partner asked, nothing applied,
    no audit line: nothing changed). The observer and controller nodes ask for this: their gate
    asks the other node of the pair, and a resent request must not do that again."""
    if take_repeats:
        repeat = []                   # the request on_set took as a repeat, until its post_set

        def on_set_or_repeat(params):
            if repeats_current(node, params):
                repeat[:] = [params]
                from rcl_interfaces.msg import SetParametersResult
                return SetParametersResult(successful=True)
            repeat.clear()
            return on_set(params)

        def post_set_unless_repeat(params):
            if repeat and repeat[0] is params:
                repeat.clear()
                return
            post_set(params)
        node.add_on_set_parameters_callback(on_set_or_repeat)
        node.add_post_set_parameters_callback(post_set_unless_repeat)
        return
    node.add_on_set_parameters_callback(on_set)
    node.add_post_set_parameters_callback(post_set)


def _plain(value):
    return list(value) if isinstance(value, (list, tuple, array)) else value


#: parameters that name a file read when they are set: setting the same path again reads the
#: file again (its contents may have changed), so a request with one is never a repeat
RELOADED = ("model_file",)


def repeats_current(node, params) -> bool:
    """Whether the request ``params`` sets every parameter to the value it has now: a repeat
    (a caller's resent request, :func:`~reachset_ros.nodes.common.call_parameter_service`),
    which changes nothing, so nothing is to be checked or applied. A gate run again for it
    costs seconds and asks the other node of the pair while that one may be asking back (a CI
    run's operator test wedged both nodes for minutes that way); an observer would also
    restart its states. A request that names a :data:`RELOADED` parameter is not a repeat."""
    return bool(params) and all(p.name not in RELOADED and node.has_parameter(p.name)
                                and _plain(node.get_parameter(p.name).value) == _plain(p.value) for p in params)
