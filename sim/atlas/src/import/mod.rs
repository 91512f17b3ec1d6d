//! Importers for real CT (filled below).
