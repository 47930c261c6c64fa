"""SOVD REST routes, one blueprint per resource."""
