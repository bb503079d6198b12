# Link strategies' shared algorithms (candidate retrieval, greedy matching).
