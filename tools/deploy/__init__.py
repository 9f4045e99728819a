"""Deploying on a real chair: the pre-flight check (``doctor``) and the systemd unit
(``install-service``); ``templates/`` (package data) holds the chair config template and the
unit for docs/deploy.md's paths, the guide is docs/deploy.md."""
