"""The one error type of the front end for anything a user can get wrong, and usd-core's
errors in a user's words."""
import re


class UserError(Exception):
    """Bad input, reported as one line `object.attribute: message` and exit status 2.

    object is a prim path (or a file, or "command line"); attribute the USD property
    (or option) at fault, empty when the object as a whole is.
    """

    def __init__(self, obj, attribute, message):
        self.object = str(obj)
        self.attribute = attribute or ""
        self.message = message
        super().__init__(f"{self.object}{'.' + self.attribute if self.attribute else ''}: {message}")


def describe_tf_error(e):
    """The messages of a Tf.ErrorException on one line (without source locations)."""
    msgs = []
    for line in str(e).splitlines():
        line = line.strip()
        if not line:
            continue
        # "Error in 'Func' at line N in file F : 'message'"
        if " : '" in line:
            line = line.split(" : '", 1)[1].rstrip("'")
        msgs.append(re.sub(r"pxrInternal_v\w+?__pxrReserved__::", "", line))
    return " ".join(msgs[:1]) if msgs else str(e).strip()
