//! Light inference from an exported bundle (to come: see the project issues).
