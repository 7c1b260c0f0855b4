"""One exception type, as rekon::Error: its message is the one line a person
reads (what is wrong, naming the thing, and what to do)."""


class Error(Exception):
    pass
