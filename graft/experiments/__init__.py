"""`graft experiment`: the paper's figures as data, run over seeds on Ray, their
statistics (bootstrap intervals, IQM) and plots."""
