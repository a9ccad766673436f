"""Errors that the public API raises."""


class ConfigError(ValueError):
    """Invalid input: names the key path and, when known, the file and line."""

    def __init__(self, message, key=None, line=None, file=None):
        self.message, self.key, self.line, self.file = message, key, line, file
        where = []
        if file:
            where.append(str(file) + (f":{line}" if line else ""))
        elif line:
            where.append(f"line {line}")
        if key:
            where.append(f"key '{key}'")
        super().__init__(f"{', '.join(where)}: {message}" if where else message)


class InstabilityError(RuntimeError):
    """A numerical failure: names step, time, particle index and cause."""

    def __init__(self, cause, step, time, particle=None, detail=""):
        self.cause, self.step, self.time, self.particle = cause, step, time, particle
        msg = f"numerical instability at step {step}, t={time:.6g}: {cause}"
        if particle is not None:
            msg += f" (particle {particle})"
        if detail:
            msg += f"; {detail}"
        super().__init__(msg)
