"""A fleet of filter workers over a Zenoh router mesh (issue #19; docs/fleet.md)."""
