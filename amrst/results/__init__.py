"""What a registration hands over: the result documents, the export, the HTML report and what each metric means."""
