"""What a failing acceptance test says about the controller (``tests[].failed_by`` in the report).

* ``"budget"``: only budgets were missed (``hil_budget`` records each miss and lets the test go
  on; the test fails with all of them when its body returns): evidence against the controller,
  and each requirement the test traces to has its own budgets' verdict.
* ``"assertion"``: a judged figure missed its bound (a stated pass/fail check of the test's
  requirement, or a budget beside a failed check): evidence against the controller.
* ``"device failure"``: the controller signalled its own failure while being judged on valid
  input (a Modbus exception 04, server device failure; an SDO abort 0x08000000, general error, or
  0x06060000, hardware error): a failed requirement, not an error of the framework.
* ``"not judged"``: a setup check found that the scenario did not provoke what the test judges
  (``not_judged(...)``): the test says nothing either way, and nothing was caught.
* ``"error"``: anything else; the test could not judge.
"""

from __future__ import annotations

import re

#: the answers by which a device says that it failed, not that the request was bad (Modbus
#: Application Protocol V1.1b3 section 7: code 04 SERVER DEVICE FAILURE; CiA 301 Table 22: SDO abort
#: 0x08000000 general error, 0x06060000 access failed due to a hardware error)
DEVICE_FAILURE = re.compile(r"refused with (exception code 0?4\b|SDO abort 0x(08000000|06060000)\b)")


class NotJudged(Exception):
    """A setup check failed: the scenario did not provoke what the test judges."""


def not_judged(ok: bool, why: str) -> None:
    """A setup check: unless ``ok``, the test stops "not judged" (``why`` says what did not happen)."""
    if not ok:
        raise NotJudged(f"not judged: {why}")


def device_failure(exc: BaseException) -> str | None:
    """The device's own failure signal ``exc`` (or its cause) carries, as its message; None if none.
    A link may mark it itself (``exc.device_failure``)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        flag = getattr(exc, "device_failure", None)
        if flag:
            return str(exc)
        if type(exc).__name__ in ("LinkError", "LinkTimeout") and DEVICE_FAILURE.search(str(exc)):
            return str(exc)
        exc = exc.__cause__ or exc.__context__
    return None
