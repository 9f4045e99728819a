"""The paper's experiments: the campaign plan and its execution, the results (rank, confidence
intervals, convexity), the report and the figures."""
