//! Training, fine-tuning and bundle export (to come: see the project issues).
