"""independent truths: code that shares nothing with the model it scores"""
