"""What a run measured: tracking errors against the bench's ground truth, command activity and
the fault diagnosis's scores, computed from the frames of a run."""
