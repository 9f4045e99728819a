"""The program that runs on the chair: link, arming, estimation, planner, tracking, safety, loop."""
