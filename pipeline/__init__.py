"""The data path of slamobs: readers -> alignment -> observers -> writers -> evaluation."""
