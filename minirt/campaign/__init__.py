"""minirt.campaign.campaign."""
