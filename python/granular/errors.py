"""The one error type of the front end for anything a user can get wrong."""


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
