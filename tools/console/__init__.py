"""What the long commands show on the terminal besides their results: progress on stderr
(``progress``), so that stdout stays the command's output."""
