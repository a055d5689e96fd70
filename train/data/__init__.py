"""The data every model sees, from file to rows: reading crane-session files (session), other rigs' logs
written as sessions (importer), the paper's filters (filters) and preprocessing (preprocess) into the
Dataset (dataset), the dead-zone masks (masks) and the disjoint training/validation/test splits
(splits)."""
