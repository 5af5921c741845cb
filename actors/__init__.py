"""Acting: env actors that step environments with an algorithm's behaviour policy and write
transitions to replay, the evaluator, and the hard-coded policies graft improves."""
