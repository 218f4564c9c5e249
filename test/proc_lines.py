"""The stdout lines of a child process as they come, read from the pipe itself: a buffered
readline after select() can take in several lines at once, which select() then no longer
sees, so a wait for the second of them would hang."""
import codecs
import os
import re
import select
import time


class Lines:
    """Lines read so far (``seen``) and a wait for the next one containing some text."""

    def __init__(self, stream) -> None:
        self._fd = stream.fileno()
        self._decode = codecs.getincrementaldecoder('utf-8')(errors='replace').decode
        self._text = ''             # read, not yet split into lines
        self.seen: list[str] = []
        self.closed = False

    def wait_for(self, text: str, timeout: float) -> str | None:
        """The first line from here on containing ``text``; None after ``timeout`` [s] or at
        the end of the output."""
        deadline = time.monotonic() + timeout
        while True:
            line = self._next(deadline)
            if line is None or text in line:
                return line

    def match(self, pattern: str, timeout: float) -> re.Match | None:
        """The match of the first line from here on that ``pattern`` is found in (re.search);
        None after ``timeout`` [s] or at the end of the output."""
        deadline = time.monotonic() + timeout
        while True:
            line = self._next(deadline)
            found = None if line is None else re.search(pattern, line)
            if line is None or found:
                return found

    def leftover(self) -> str:
        """What was read but not returned as a line yet (prepend it to a later read)."""
        text, self._text = self._text, ''
        return text

    def _next(self, deadline: float) -> str | None:
        while '\n' not in self._text:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or self.closed:
                return None
            ready, _, _ = select.select([self._fd], [], [], min(0.2, remaining))
            if ready:
                chunk = os.read(self._fd, 65536)
                self.closed = not chunk
                self._text += self._decode(chunk, final=self.closed)
        line, self._text = self._text.split('\n', 1)
        self.seen.append(line + '\n')
        return line + '\n'
