"""Sessions in the database: packed sample and estimate blocks, a session as a
recording (and back), and the batch processing that stores a session's estimates."""
