"""Parameters from records: the least-squares problem and its polish, the paper's genetic
search, intervals and determined combinations, what a record's own unknowns may physically
be, noise floors, scores and predictions of fitted models on other records.
"""
