"""Deploying on a real chair: the pre-flight check (``doctor``) and the systemd unit
(``install-service``); the chair config template and the guide are docs/deploy/ and
docs/deploy.md."""
