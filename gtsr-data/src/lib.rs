//! Dataset loaders and the synthetic scene generator (in progress; see the gtsr-data issue).
